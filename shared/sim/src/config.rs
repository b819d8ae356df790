//! The TOML configuration shared by `hydractl sim` and, later, every live
//! process: one file describes plant, sensors, effects, controllers and
//! reference. Unknown keys are errors, so a typo never silently falls back
//! to a default.

use std::path::{Path, PathBuf};

use hydractl_control::{
    FrictionCompensatorParams, HInfinityParams, MfcParams, PidParams, Trajectory, ValveShaperParams,
    VelocityEstimatorParams,
};
use hydractl_plant::{EffectsConfig, PlantParams, SensorParams};
use serde::{Deserialize, Serialize};

#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("cannot read config {path}: {source}")]
    Read { path: PathBuf, source: std::io::Error },
    #[error("config {path}: {message}")]
    Parse { path: PathBuf, message: String },
    #[error("config {path}: [{section}] {source}")]
    Plant {
        path: PathBuf,
        section: &'static str,
        source: hydractl_plant::PlantError,
    },
    #[error("config {path}: [{section}] {source}")]
    Control {
        path: PathBuf,
        section: &'static str,
        source: hydractl_control::ControlError,
    },
    #[error("config {path}: [timing] {reason}")]
    Timing { path: PathBuf, reason: String },
    #[error("config {path}: [supervisor] {reason}")]
    Supervisor { path: PathBuf, reason: String },
}

/// Position-only: the outer loop drives the valve. Cascade: the outer loop
/// gives a torque reference to the inner torque loop.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Structure {
    Position,
    Cascade,
}

impl Structure {
    pub fn name(self) -> &'static str {
        match self {
            Structure::Position => "position",
            Structure::Cascade => "cascade",
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PositionVariant {
    Pid,
    Mfc,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TorqueVariant {
    Pid,
    Hinf,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Timing {
    /// Control loop rate, Hz (the papers' dSPACE loops; 1 kHz).
    pub control_rate_hz: f64,
    /// Plant integration rate, Hz; an integer multiple of the control rate.
    pub integration_rate_hz: f64,
    /// The CPU the live loop's processes (plant, sensor, friction,
    /// position, torque, valve) are pinned to; none to let the scheduler
    /// place them. A wake-up across cores costs about 25 µs per hop on a
    /// small virtual machine; on one core the pipeline's hand-offs are cheap.
    pub loop_cpu: Option<usize>,
    /// SCHED_FIFO priority (1–98) of the live loop's processes; none for
    /// the normal scheduler. Above every ordinary process, a stage is never
    /// preempted by one, only by the kernel and by higher real-time work;
    /// the kernel's real-time throttling (95% of each second by default)
    /// still leaves the CPU to others should a stage spin.
    pub realtime_priority: Option<u8>,
    /// Held for the run through the kernel's PM QoS request: no CPU enters
    /// an idle state slower to leave than this, µs; none to let CPUs sleep
    /// as deeply as they like. 0 keeps idle CPUs polling, so that a stage
    /// woken by its input runs at once: on this virtual machine a halted
    /// virtual CPU takes about 25 µs to wake, and the loop wakes at every
    /// hop. Costs power on idle CPUs; needs root.
    pub cpu_dma_latency_us: Option<u32>,
    /// Move device interrupts off `loop_cpu` for the run: their handlers
    /// preempt even a real-time stage. Needs root and a `loop_cpu`.
    pub interrupts_off_loop_cpu: bool,
    /// What the live plant process does when the computer stalls.
    pub stall_policy: StallPolicy,
    /// How long, in periods, the paused plant waits for a command before it
    /// counts a deadline miss and goes on with the valve's last command.
    pub command_timeout_periods: f64,
}

/// A stalled computer delays the loop. A simulated plant can wait for it
/// (`pause`: its time is the loop's, so it stays exactly the offline
/// simulation); a machine cannot (`catch_up`: physics runs on with the
/// valve's last command, as a stand-in for real hardware).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StallPolicy {
    Pause,
    CatchUp,
}

impl Default for Timing {
    fn default() -> Self {
        Self {
            control_rate_hz: 1000.0,
            integration_rate_hz: 10_000.0,
            loop_cpu: None,
            realtime_priority: None,
            cpu_dma_latency_us: None,
            interrupts_off_loop_cpu: false,
            stall_policy: StallPolicy::Pause,
            command_timeout_periods: 1.5,
        }
    }
}

impl Timing {
    pub fn control_period(&self) -> f64 {
        1.0 / self.control_rate_hz
    }

    pub fn integration_step(&self) -> f64 {
        1.0 / self.integration_rate_hz
    }

    pub fn substeps(&self) -> usize {
        (self.integration_rate_hz / self.control_rate_hz).round() as usize
    }
}

/// The outer loop of one structure: its output is a valve command
/// (position-only) or a torque in N·m (cascade), so each structure has its
/// own variant and gains.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OuterLoopConfig {
    /// The variant in charge when this structure runs.
    pub variant: PositionVariant,
    pub pid: PidParams,
    pub mfc: MfcParams,
    pub friction: FrictionCompensatorParams,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TorqueLoopConfig {
    /// Valve command per rad/s of reference velocity, added to either
    /// variant's output: the flow the motion needs, 1 / (rad/s per unit
    /// command), taken from the reference so that it adds no velocity
    /// feedback to undo the damping the torque loop gives. 0 switches it off.
    #[serde(default)]
    pub velocity_feedforward: f64,
    /// Valve command per N·m/s of torque-reference rate, added to either
    /// variant's output. Pressure integrates flow, so the command that makes
    /// torque rise at rate τ̇ is τ̇ / (D β/V 4 K_q); without it an inner loop
    /// lags a moving reference. Not in the papers; 0 switches it off.
    #[serde(default)]
    pub rate_feedforward: f64,
    /// Time constant of the low-pass filter on the differenced reference, s.
    #[serde(default = "default_rate_filter")]
    pub rate_filter_s: f64,
    pub pid: PidParams,
    #[serde(default)]
    pub hinf: HInfinityParams,
}

fn default_rate_filter() -> f64 {
    0.005
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ControlConfig {
    pub structure: Structure,
    pub torque_variant: TorqueVariant,
    #[serde(default)]
    pub velocity_estimator: VelocityEstimatorParams,
    pub position_only: OuterLoopConfig,
    pub cascade: OuterLoopConfig,
    pub torque: TorqueLoopConfig,
    #[serde(default)]
    pub valve: ValveShaperParams,
    #[serde(default)]
    pub valve_guard: ValveGuardParams,
}

/// The valve's last line of safety.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ValveGuardParams {
    /// A command derived from a sensor reading more than this many periods
    /// older than the newest one puts the valve in neutral.
    pub max_age_periods: u64,
    /// With neither readings nor commands for this long, ms, the loop
    /// upstream is gone and the valve goes to neutral on its own clock.
    /// Longer than the stalls of a busy computer (up to 10 ms seen here).
    pub silence_timeout_ms: f64,
    /// A limit cycle: `limit_cycle_reversals` reversals of the requested
    /// command in a row, each a swing of at least `limit_cycle_swing`
    /// (command units, peak to peak) within `limit_cycle_half_period_periods`
    /// of the one before. The valve then stays neutral until the commands
    /// stop (their controller replaced). 0 reversals: no check.
    pub limit_cycle_swing: f64,
    pub limit_cycle_half_period_periods: u64,
    pub limit_cycle_reversals: u64,
}

impl Default for ValveGuardParams {
    fn default() -> Self {
        Self {
            max_age_periods: 3,
            silence_timeout_ms: 20.0,
            limit_cycle_swing: 1.0,
            limit_cycle_half_period_periods: 150,
            limit_cycle_reversals: 12,
        }
    }
}

/// How the supervisor watches the live processes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SupervisorConfig {
    /// A process whose output stops for this long while its input flows is
    /// hung: it is killed and restarted.
    pub hung_after_ms: u64,
    /// First delay before a restart; doubles per consecutive failure.
    pub restart_backoff_initial_ms: u64,
    pub restart_backoff_max_ms: u64,
    /// A process up this long has its back-off reset.
    pub healthy_after_ms: u64,
    /// How long a stopping process may take before it is killed.
    pub stop_timeout_ms: u64,
    /// When a process that stopped is started again, for every process…
    pub restart: RestartRule,
    /// …unless `[supervisor.processes.NAME]` says otherwise for one.
    pub processes: std::collections::BTreeMap<String, RestartRule>,
    /// With a machine: no reading from it for this many control periods
    /// and the stack goes on against the simulated plant.
    pub machine_lost_after_periods: u64,
    /// A controller whose commands the valve rejects (NaN, out of range)
    /// this many times within twice as many readings misbehaves: it is
    /// killed and restarted…
    pub misbehaving_after_periods: u64,
    /// …into this variant, per stage (`position`, `torque`), when given.
    pub fallback_variants: std::collections::BTreeMap<String, String>,
}

impl Default for SupervisorConfig {
    fn default() -> Self {
        Self {
            hung_after_ms: 50,
            restart_backoff_initial_ms: 30,
            restart_backoff_max_ms: 2000,
            healthy_after_ms: 5000,
            stop_timeout_ms: 1000,
            restart: RestartRule::default(),
            processes: std::collections::BTreeMap::new(),
            machine_lost_after_periods: 10,
            misbehaving_after_periods: 10,
            fallback_variants: std::collections::BTreeMap::new(),
        }
    }
}

/// The processes a supervisor's restart rules may name.
pub const SUPERVISED_PROCESSES: [&str; 8] = [
    "plant", "machine", "sensor", "friction", "position", "torque", "valve", "recorder",
];

impl SupervisorConfig {
    /// The restart rule of `process`.
    pub fn restart_rule(&self, process: &str) -> &RestartRule {
        self.processes.get(process).unwrap_or(&self.restart)
    }
}

/// Whether a stopped process is started again.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum RestartPolicy {
    /// Whatever the reason it stopped.
    #[default]
    Always,
    /// When it crashed, was killed or hung; not after a clean exit (0).
    OnFailure,
    /// Never: it stays down (a controller's valve stays neutral).
    Never,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RestartRule {
    pub policy: RestartPolicy,
    /// At most this many restarts within `window_s`; past it, the process
    /// is left down and the supervisor says so.
    pub max_restarts: u32,
    pub window_s: f64,
}

impl Default for RestartRule {
    fn default() -> Self {
        Self {
            policy: RestartPolicy::Always,
            max_restarts: 20,
            window_s: 60.0,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SimulationConfig {
    /// Seed of the sensor noise; the same seed gives the same run.
    pub seed: u64,
}

impl ControlConfig {
    /// The outer loop of the structure in charge.
    pub fn outer(&self) -> &OuterLoopConfig {
        match self.structure {
            Structure::Position => &self.position_only,
            Structure::Cascade => &self.cascade,
        }
    }
}

impl Default for SimulationConfig {
    fn default() -> Self {
        Self { seed: 1 }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    #[serde(default)]
    pub simulation: SimulationConfig,
    #[serde(default)]
    pub timing: Timing,
    #[serde(default)]
    pub plant: PlantParams,
    #[serde(default)]
    pub sensor: SensorParams,
    /// Effects switched on in the simulated plant; none by default.
    #[serde(default)]
    pub effects: EffectsConfig,
    pub control: ControlConfig,
    #[serde(default)]
    pub trajectory: Trajectory,
    #[serde(default)]
    pub supervisor: SupervisorConfig,
    /// The machine the stack drives, when it is not the simulated plant:
    /// here a stand-in process with its own parameters and effects (on the
    /// vehicle, the machine's devices). With it, the simulated plant waits
    /// in standby and takes over when the machine is lost.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub machine: Option<MachineConfig>,
}

/// The machine stand-in: the simulated plant's parameters, overridden.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(default, deny_unknown_fields)]
pub struct MachineConfig {
    /// `[plant]` keys that differ on the machine.
    pub plant: toml::Table,
    /// The machine's own effects (the model's `[effects]` do not apply).
    pub effects: EffectsConfig,
    /// Its sensor noise seed, for a machine that is not the model's twin.
    pub seed: Option<u64>,
    /// The stand-in's sensor bus goes silent this long after it starts, as
    /// a lost CAN bus would: for trying the fallback.
    pub bus_lost_after_s: Option<f64>,
}

/// How deep `base = "FILE"` may chain.
const MAX_BASE_DEPTH: usize = 4;

impl Config {
    /// Loads a config file. A file may start from another with
    /// `base = "OTHER.toml"` (relative to itself) and give only what
    /// differs: its tables are merged over the base's, key by key.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
            path: path.to_owned(),
            source,
        })?;
        if !text.lines().any(|l| l.trim_start().starts_with("base")) {
            return Self::parse(&text, path);
        }
        let table = Self::load_table(path, &text, 0)?;
        let config = Config::deserialize(toml::Value::Table(table)).map_err(|e| ConfigError::Parse {
            path: path.to_owned(),
            message: e.to_string(),
        })?;
        config.validate(path)?;
        Ok(config)
    }

    fn load_table(path: &Path, text: &str, depth: usize) -> Result<toml::Table, ConfigError> {
        let parse_error = |message: String| ConfigError::Parse {
            path: path.to_owned(),
            message,
        };
        let mut table: toml::Table = toml::from_str(text).map_err(|e| parse_error(e.to_string()))?;
        let Some(base) = table.remove("base") else {
            return Ok(table);
        };
        let Some(base) = base.as_str() else {
            return Err(parse_error("`base` must be a file name".into()));
        };
        if depth >= MAX_BASE_DEPTH {
            return Err(parse_error(format!("`base` chains deeper than {MAX_BASE_DEPTH} files")));
        }
        let base_path = path.parent().unwrap_or(Path::new(".")).join(base);
        let base_text = std::fs::read_to_string(&base_path).map_err(|source| ConfigError::Read {
            path: base_path.clone(),
            source,
        })?;
        let mut merged = Self::load_table(&base_path, &base_text, depth + 1)?;
        merge_tables(&mut merged, table);
        Ok(merged)
    }

    /// The machine stand-in's own config: this one with the machine's
    /// plant parameters, effects and seed. `None` when there is no machine.
    pub fn machine_plant(&self) -> Result<Option<Config>, ConfigError> {
        let Some(machine) = &self.machine else {
            return Ok(None);
        };
        let error = |message: String| ConfigError::Parse {
            path: PathBuf::from("[machine]"),
            message,
        };
        let mut plant = toml::Table::try_from(self.plant).map_err(|e| error(e.to_string()))?;
        merge_tables(&mut plant, machine.plant.clone());
        let mut config = self.clone();
        config.plant =
            PlantParams::deserialize(toml::Value::Table(plant)).map_err(|e| error(format!("[machine.plant] {e}")))?;
        config.effects = machine.effects.clone();
        if let Some(seed) = machine.seed {
            config.simulation.seed = seed;
        }
        config.machine = None;
        Ok(Some(config))
    }

    /// Parses and validates; `path` only names the source in errors.
    pub fn parse(text: &str, path: &Path) -> Result<Self, ConfigError> {
        let config: Config = toml::from_str(text).map_err(|e| ConfigError::Parse {
            path: path.to_owned(),
            message: e.to_string(),
        })?;
        config.validate(path)?;
        Ok(config)
    }

    /// The config as TOML, for a recording's metadata.
    pub fn to_toml(&self) -> String {
        toml::to_string(self).unwrap_or_else(|e| format!("# the config cannot be written as TOML: {e}"))
    }

    /// The file's config, or the built-in default when no file is given.
    pub fn load_or_default(path: Option<&Path>) -> Result<Self, ConfigError> {
        match path {
            Some(path) => Self::load(path),
            None => Self::default_sim(),
        }
    }

    /// The default simulated rotator, compiled in so that tests and a bare
    /// `hydractl sim` agree with `config/sim.toml`.
    pub fn default_sim() -> Result<Self, ConfigError> {
        Self::parse(DEFAULT_SIM_TOML, Path::new("config/sim.toml"))
    }

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
        if let Some(after) = self.machine.as_ref().and_then(|m| m.bus_lost_after_s) {
            if !(after.is_finite() && after > 0.0) {
                return Err(ConfigError::Parse {
                    path: path.to_owned(),
                    message: format!("[machine] bus_lost_after_s must be positive, got {after}"),
                });
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
        ] {
            if value == 0 {
                return Err(ConfigError::Supervisor {
                    path: path.to_owned(),
                    reason: format!("{name} must be above 0"),
                });
            }
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
        if sup.restart_backoff_max_ms < sup.restart_backoff_initial_ms {
            return Err(ConfigError::Supervisor {
                path: path.to_owned(),
                reason: "restart_backoff_max_ms must be at least restart_backoff_initial_ms".into(),
            });
        }
        // Building every stage validates every controller's parameters.
        crate::stack::ControlStack::new(self).map_err(|e| match e {
            crate::stack::StackError::Control { section, source } => ConfigError::Control {
                path: path.to_owned(),
                section,
                source,
            },
        })?;
        Ok(())
    }
}

pub const DEFAULT_SIM_TOML: &str = include_str!("../../../config/sim.toml");

/// Merges `over` into `base`: tables key by key, anything else replaced.
fn merge_tables(base: &mut toml::Table, over: toml::Table) {
    for (key, value) in over {
        match (base.get_mut(&key), value) {
            (Some(toml::Value::Table(b)), toml::Value::Table(o)) => merge_tables(b, o),
            (_, value) => {
                base.insert(key, value);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_machine_config_starts_from_its_base_and_overrides_the_plant() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/machine.toml");
        let config = Config::load(&path).expect("config/machine.toml");
        assert_eq!(config.plant.inertia, 20.0, "the model is sim.toml's");
        assert_eq!(config.supervisor.machine_lost_after_periods, 10);
        let machine = config.machine_plant().expect("valid").expect("a machine");
        assert_eq!(machine.plant.inertia, 22.0);
        assert_eq!(machine.plant.supply_pressure, config.plant.supply_pressure);
        assert!(machine.effects.0.contains_key("coulomb_friction"));
        assert!(config.effects.0.is_empty());

        let dir = std::env::temp_dir().join(format!("hydractl-config-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("dir");
        let bad = dir.join("bad.toml");
        std::fs::write(
            &bad,
            format!(
                "base = {:?}\n[machine.plant]\ninertai = 1.0\n",
                path.display().to_string()
            ),
        )
        .expect("write");
        let err = Config::load(&bad).expect_err("a misspelt key").to_string();
        assert!(err.contains("machine.plant") && err.contains("inertai"), "{err}");
        std::fs::write(&bad, "base = \"missing.toml\"\n").expect("write");
        let err = Config::load(&bad).expect_err("a missing base").to_string();
        assert!(err.contains("missing.toml"), "{err}");
        std::fs::remove_dir_all(dir).ok();
    }

    #[test]
    fn built_in_default_parses() {
        let c = Config::parse(DEFAULT_SIM_TOML, Path::new("config/sim.toml")).expect("valid");
        assert_eq!(c.timing.substeps(), 10);
        assert!(c.effects.0.is_empty(), "the default plant has no effects");
    }

    #[test]
    fn restart_rules_parse_and_bad_ones_are_named() {
        let text =
            format!("{DEFAULT_SIM_TOML}\n[supervisor.processes.valve]\npolicy = \"on-failure\"\nmax_restarts = 3\n");
        let c = Config::parse(&text, Path::new("x.toml")).expect("valid");
        assert_eq!(c.supervisor.restart_rule("valve").policy, RestartPolicy::OnFailure);
        assert_eq!(c.supervisor.restart_rule("valve").max_restarts, 3);
        assert_eq!(c.supervisor.restart_rule("sensor").policy, RestartPolicy::Always);
        let unknown = format!("{DEFAULT_SIM_TOML}\n[supervisor.processes.valv]\npolicy = \"never\"\n");
        let e = Config::parse(&unknown, Path::new("x.toml")).expect_err("no such process");
        assert!(e.to_string().contains("supervisor.processes.valv"), "{e}");
        let bad = format!("{DEFAULT_SIM_TOML}\n[supervisor.processes.valve]\npolicy = \"sometimes\"\n");
        let e = Config::parse(&bad, Path::new("x.toml")).expect_err("no such policy");
        assert!(e.to_string().contains("sometimes"), "{e}");
    }

    #[test]
    fn unknown_keys_and_bad_values_name_the_place() {
        let bad = DEFAULT_SIM_TOML.replace("inertia = ", "inertiaa = ");
        let err = Config::parse(&bad, Path::new("x.toml")).expect_err("unknown key");
        let text = err.to_string();
        assert!(text.contains("x.toml") && text.contains("inertiaa"), "{text}");

        let bad = DEFAULT_SIM_TOML.replace("inertia = 20.0", "inertia = -1.0");
        let err = Config::parse(&bad, Path::new("x.toml")).expect_err("negative");
        assert!(
            err.to_string().contains("[plant]") && err.to_string().contains("inertia"),
            "{err}"
        );

        let bad = format!("{DEFAULT_SIM_TOML}\n[effects.dedzone]\n");
        let err = Config::parse(&bad, Path::new("x.toml")).expect_err("unknown effect");
        assert!(err.to_string().contains("deadzone"), "lists the valid names: {err}");

        let bad = DEFAULT_SIM_TOML.replace("loop_cpu = 1 ", "# no loop CPU ");
        let err = Config::parse(&bad, Path::new("x.toml")).expect_err("interrupts off no CPU");
        assert!(err.to_string().contains("interrupts_off_loop_cpu"), "{err}");

        let bad = DEFAULT_SIM_TOML.replace("realtime_priority = 50", "realtime_priority = 99");
        let err = Config::parse(&bad, Path::new("x.toml")).expect_err("the kernel's priority");
        assert!(
            err.to_string().contains("x.toml") && err.to_string().contains("realtime_priority"),
            "{err}"
        );
    }
}
