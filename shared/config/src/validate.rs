//! Everything a loaded config is checked for, each error naming its file
//! and section.

use std::path::Path;

use crate::{Config, ConfigError, SUPERVISED_PROCESSES};

impl Config {
    pub fn validate(&self, path: &Path) -> Result<(), ConfigError> {
        let plant = |section: &'static str| {
            move |source| ConfigError::Plant {
                path: path.to_owned(),
                section,
                source,
            }
        };
        let control = |section: &'static str| {
            move |source| ConfigError::Control {
                path: path.to_owned(),
                section,
                source,
            }
        };
        self.plant.validate().map_err(plant("plant"))?;
        self.sensor.validate().map_err(plant("sensor"))?;
        self.effects.build().map_err(plant("effects"))?;
        self.trajectory.validate().map_err(control("trajectory"))?;
        if let Some(machine) = self.machine_plant().map_err(|e| match e {
            ConfigError::Parse { message, .. } => ConfigError::Parse {
                path: path.to_owned(),
                message,
            },
            other => other,
        })? {
            machine.plant.validate().map_err(plant("machine.plant"))?;
            machine.effects.build().map_err(plant("machine.effects"))?;
        }
        if let Some(drift) = self.machine.as_ref().and_then(|m| m.drift.as_ref()) {
            let effects = self
                .machine_plant()?
                .map(|m| m.effects.build())
                .transpose()
                .map_err(plant("machine.effects"))?
                .unwrap_or_default();
            hydractl_plant::Drift::new(&effects, drift).map_err(plant("machine.drift"))?;
        }
        let shadow = &self.shadow;
        let segments = |s: f64| s / 0.5;
        for (key, value) in [
            ("window_s", shadow.window_s),
            ("every_s", shadow.every_s),
            ("diagnose_s", shadow.diagnose_s),
        ] {
            if !(value.is_finite() && value >= 0.5 && (segments(value) - segments(value).round()).abs() < 1e-9) {
                return Err(ConfigError::Parse {
                    path: path.to_owned(),
                    message: format!(
                        "[shadow] {key} must be a whole number of 0.5 s segments, at least one; got {value}"
                    ),
                });
            }
        }
        // The model tools compare and fit on 4 s of data at least.
        if shadow.every_s > shadow.window_s || shadow.window_s < 4.0 || shadow.diagnose_s < 4.0 {
            return Err(ConfigError::Parse {
                path: path.to_owned(),
                message: format!(
                    "[shadow] every_s ({}) must be within window_s ({}), and window_s and diagnose_s ({}) at least 4 s",
                    shadow.every_s, shadow.window_s, shadow.diagnose_s
                ),
            });
        }
        if let Some(after) = self.machine.as_ref().and_then(|m| m.bus_lost_after_s) {
            if !(after.is_finite() && after > 0.0) {
                return Err(ConfigError::Parse {
                    path: path.to_owned(),
                    message: format!("[machine] bus_lost_after_s must be positive, got {after}"),
                });
            }
        }
        let machine = self.machine.as_ref();
        for (table, after_s) in [
            ("silent_node", machine.and_then(|m| m.silent_node).map(|s| s.after_s)),
            ("stuck_spool", machine.and_then(|m| m.stuck_spool).map(|s| s.after_s)),
        ] {
            if let Some(after_s) = after_s.filter(|a| !(a.is_finite() && *a > 0.0)) {
                return Err(ConfigError::Parse {
                    path: path.to_owned(),
                    message: format!("[machine.{table}] after_s must be positive, got {after_s}"),
                });
            }
        }
        if let Some(can) = &self.can {
            let profile = can.resolve().map_err(|source| ConfigError::Can {
                path: path.to_owned(),
                source,
            })?;
            if self.timing.control_rate_hz.is_finite() && self.timing.control_rate_hz > 0.0 {
                let period_us = 1e6 / self.timing.control_rate_hz;
                // The chain answers after the deadline and before the next
                // SYNC: a deadline past 80 % of the period leaves it no time.
                if f64::from(profile.pdo_deadline_us) > 0.8 * period_us {
                    return Err(ConfigError::Can {
                        path: path.to_owned(),
                        source: hydractl_can::profile::ProfileError {
                            section: String::new(),
                            reason: format!(
                                "pdo_deadline_us = {} is past 80 % of the {period_us:.0} µs period: the loop would have no time to answer before the next SYNC",
                                profile.pdo_deadline_us
                            ),
                        },
                    });
                }
                let silence_tick_ms = self.control.valve_guard.silence_timeout_ms / 4.0;
                // The one rule for the valve's own timeout (SAFETY.md, H12):
                // a living valve process sends its set point at least every
                // tick, so three ticks without one is a dead process.
                if 3.0 * silence_tick_ms > f64::from(profile.valve_rpdo_timeout_ms) {
                    return Err(ConfigError::Can {
                        path: path.to_owned(),
                        source: hydractl_can::profile::ProfileError {
                            section: ".valve".into(),
                            reason: format!(
                                "rpdo_timeout_ms = {} is too short for the valve process's {silence_tick_ms} ms tick \
                                 ([control.valve_guard] silence_timeout_ms / 4), on which it sends its set point again: at least three ticks",
                                profile.valve_rpdo_timeout_ms
                            ),
                        },
                    });
                }
                let budget = profile.budget((1e9 / self.timing.control_rate_hz) as u64);
                if !budget.fits {
                    return Err(ConfigError::CanBudget {
                        path: path.to_owned(),
                        table: budget.table(),
                    });
                }
            }
        }
        let t = &self.timing;
        if !(t.control_rate_hz.is_finite() && t.control_rate_hz > 0.0 && t.integration_rate_hz.is_finite()) {
            return Err(ConfigError::Timing {
                path: path.to_owned(),
                reason: "control_rate_hz and integration_rate_hz must be positive and finite".into(),
            });
        }
        if !(t.command_timeout_periods.is_finite() && t.command_timeout_periods > 0.0) {
            return Err(ConfigError::Timing {
                path: path.to_owned(),
                reason: format!(
                    "command_timeout_periods must be positive, got {}",
                    t.command_timeout_periods
                ),
            });
        }
        if t.interrupts_off_loop_cpu && t.loop_cpu.is_none() {
            return Err(ConfigError::Timing {
                path: path.to_owned(),
                reason: "interrupts_off_loop_cpu needs a loop_cpu to steer them off".to_owned(),
            });
        }
        if let Some(priority) = t.realtime_priority.filter(|p| !(1..=98).contains(p)) {
            return Err(ConfigError::Timing {
                path: path.to_owned(),
                reason: format!("realtime_priority must be within 1–98 (99 is the kernel's own), got {priority}"),
            });
        }
        let ratio = t.integration_rate_hz / t.control_rate_hz;
        if ratio < 1.0 || (ratio - ratio.round()).abs() > 1e-9 {
            return Err(ConfigError::Timing {
                path: path.to_owned(),
                reason: format!(
                    "integration_rate_hz ({}) must be a whole multiple of control_rate_hz ({})",
                    t.integration_rate_hz, t.control_rate_hz
                ),
            });
        }
        let sup = &self.supervisor;
        for (name, value) in [
            ("hung_after_ms", sup.hung_after_ms),
            ("restart_backoff_initial_ms", sup.restart_backoff_initial_ms),
            ("restart_backoff_max_ms", sup.restart_backoff_max_ms),
            ("stop_timeout_ms", sup.stop_timeout_ms),
            ("machine_lost_after_periods", sup.machine_lost_after_periods),
            ("misbehaving_after_periods", sup.misbehaving_after_periods),
            ("spinning_after_ms", sup.spinning_after_ms),
            ("limit_cycle_backoff_ms", sup.limit_cycle_backoff_ms),
        ] {
            if value == 0 {
                return Err(ConfigError::Supervisor {
                    path: path.to_owned(),
                    reason: format!("{name} must be above 0"),
                });
            }
        }
        if !(sup.swap_rollback_factor.is_finite() && sup.swap_rollback_factor >= 1.0) {
            return Err(ConfigError::Supervisor {
                path: path.to_owned(),
                reason: format!(
                    "swap_rollback_factor must be at least 1 (a variant as good as the one before stays), got {}",
                    sup.swap_rollback_factor
                ),
            });
        }
        if !(sup.swap_rollback_min_rms_rad.is_finite() && sup.swap_rollback_min_rms_rad >= 0.0) {
            return Err(ConfigError::Supervisor {
                path: path.to_owned(),
                reason: format!(
                    "swap_rollback_min_rms_rad must be 0 or more, rad, got {}",
                    sup.swap_rollback_min_rms_rad
                ),
            });
        }
        if !(sup.spinning_cpu_share > 0.0 && sup.spinning_cpu_share <= 1.0) {
            return Err(ConfigError::Supervisor {
                path: path.to_owned(),
                reason: format!(
                    "spinning_cpu_share must be in (0, 1], a share of one CPU, got {}",
                    sup.spinning_cpu_share
                ),
            });
        }
        for (stage, variant) in &sup.fallback_variants {
            let allowed: &[&str] = match stage.as_str() {
                "position" => &["pid", "mfc"],
                "torque" => &["pid", "hinf"],
                _ => &[],
            };
            if !allowed.contains(&variant.as_str()) {
                return Err(ConfigError::Supervisor {
                    path: path.to_owned(),
                    reason: format!(
                        "fallback_variants.{stage} = `{variant}`: the stages are `position` (pid, mfc) and `torque` (pid, hinf)"
                    ),
                });
            }
            // A fault must not land the machine in a controller nobody
            // designed for it.
            if stage == "torque" && variant == "hinf" && self.control.torque.hinf.design.is_none() {
                return Err(ConfigError::Supervisor {
                    path: path.to_owned(),
                    reason: "fallback_variants.torque = `hinf`: [control.torque.hinf] has no [control.torque.hinf.design]: it is the crane paper's controller, designed for the crane, not this machine; design one from this machine's recording with `hydractl ident hinf --data RECORDING --out CONFIG`, or fall back to `pid`".to_owned(),
                });
            }
        }
        for name in sup.processes.keys() {
            if !SUPERVISED_PROCESSES.contains(&name.as_str()) {
                return Err(ConfigError::Supervisor {
                    path: path.to_owned(),
                    reason: format!(
                        "[supervisor.processes.{name}]: no process `{name}`; the processes are {}",
                        SUPERVISED_PROCESSES.join(", ")
                    ),
                });
            }
        }
        for (name, rule) in
            std::iter::once(("restart", &sup.restart)).chain(sup.processes.iter().map(|(n, r)| (n.as_str(), r)))
        {
            if !(rule.window_s.is_finite() && rule.window_s > 0.0) {
                return Err(ConfigError::Supervisor {
                    path: path.to_owned(),
                    reason: format!(
                        "{name}: window_s must be a positive number of seconds, got {}",
                        rule.window_s
                    ),
                });
            }
        }
        if let Some(level) = &self.log.level {
            tracing_subscriber::EnvFilter::builder()
                .parse(level)
                .map_err(|e| ConfigError::LogLevel {
                    path: path.to_owned(),
                    level: level.clone(),
                    reason: e.to_string(),
                })?;
        }
        let r = &self.recording;
        for (key, value) in [
            ("keep_mb", r.keep_mb),
            ("split_size_mb", r.split_size_mb),
            ("split_duration_s", r.split_duration_s),
        ] {
            if let Some(v) = value.filter(|v| !(v.is_finite() && *v > 0.0)) {
                return Err(ConfigError::Recording {
                    path: path.to_owned(),
                    reason: format!("{key} must be a positive number, got {v}"),
                });
            }
        }
        if sup.restart_backoff_max_ms < sup.restart_backoff_initial_ms {
            return Err(ConfigError::Supervisor {
                path: path.to_owned(),
                reason: "restart_backoff_max_ms must be at least restart_backoff_initial_ms".into(),
            });
        }
        self.control
            .check_controllers(self.timing.control_period(), self.load_model())
            .map_err(|(section, source)| ConfigError::Control {
                path: path.to_owned(),
                section,
                source,
            })
    }
}
