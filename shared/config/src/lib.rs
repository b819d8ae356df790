//! The TOML configuration shared by `hydractl sim` and every live process:
//! one file describes plant, sensors, effects, controllers, reference,
//! timing and supervision. Unknown keys are errors, so a typo never
//! silently falls back to a default; a file may start from a `base` and
//! give only what differs.
//!
//! What it holds: The TOML config: the file's sections (`timing`, `control`,
//! `supervisor`, the plant's, the machine stand-in's, `log`, `recording`),
//! loading with `base = "FILE"` chains, and validation: every key checked,
//! every controller of the structure in charge built once at load, each error
//! naming the file and section; `compensate`: the controllers' compensators
//! set from a fitted model's effects, each change with its reason.

pub mod compensate;
mod control;
mod deploy;
mod supervisor;
mod timing;
mod validate;

use std::path::{Path, PathBuf};

use hydractl_can::profile::CanConfig;
use hydractl_control::{LoadModel, Trajectory};
use hydractl_plant::{EffectsConfig, PlantParams, SensorParams};
use serde::{Deserialize, Serialize};

pub use control::{
    ControlConfig, OuterLoopConfig, OuterPart, PositionVariant, Structure, TorqueLoopConfig, TorqueVariant,
    ValveGuardParams, MAX_GUARD_PERIODS,
};
pub use deploy::{LogConfig, LogOutput, RecordingConfig, ShadowConfig};
pub(crate) use supervisor::SUPERVISED_PROCESSES;
pub use supervisor::{OnLimitCycle, RestartPolicy, RestartRule, SupervisorConfig};
pub use timing::{StallPolicy, Timing};

#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("cannot read config {path}: {source}")]
    Read { path: PathBuf, source: std::io::Error },
    #[error("config {path}: {message}")]
    Parse { path: PathBuf, message: String },
    #[error("config {path}: `base = {base:?}`: cannot read {resolved}: {source}")]
    Base {
        path: PathBuf,
        base: String,
        resolved: PathBuf,
        source: std::io::Error,
    },
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
    #[error("config {path}: [log] level = {level:?}: {reason}")]
    LogLevel {
        path: PathBuf,
        level: String,
        reason: String,
    },
    #[error("config {path}: [recording] {reason}")]
    Recording { path: PathBuf, reason: String },
    #[error("config {path}: [supervisor] {reason}")]
    Supervisor { path: PathBuf, reason: String },
    #[error("config {path}: {source}")]
    Can {
        path: PathBuf,
        source: hydractl_can::profile::ProfileError,
    },
    #[error("config {path}: [can] one period's frames do not fit the bus:\n{table}")]
    CanBudget { path: PathBuf, table: String },
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SimulationConfig {
    /// Seed of the sensor noise; the same seed gives the same run.
    pub seed: u64,
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
    /// The machine's devices on CAN: with this table the sensor and valve
    /// processes speak CANopen to them, over SocketCAN or the virtual bus.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub can: Option<CanConfig>,
    #[serde(default)]
    pub log: LogConfig,
    #[serde(default)]
    pub recording: RecordingConfig,
    #[serde(default)]
    pub shadow: ShadowConfig,
}

/// The machine stand-in: the simulated plant's parameters, overridden.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(default, deny_unknown_fields)]
pub struct MachineConfig {
    /// The machine's name in its fleet (a serial number, a fleet number):
    /// written into every recording's metadata as `machine_id`.
    pub id: Option<String>,
    /// `[plant]` keys that differ on the machine.
    pub plant: toml::Table,
    /// The machine's own effects (the model's `[effects]` do not apply).
    pub effects: EffectsConfig,
    /// Its sensor noise seed, for a machine that is not the model's twin.
    pub seed: Option<u64>,
    /// The stand-in's sensor bus goes silent this long after it starts, as
    /// a lost CAN bus would: for trying the fallback.
    pub bus_lost_after_s: Option<f64>,
    /// On the virtual CAN bus: one simulated node stops (no heartbeat, no
    /// PDOs) this long after the ECUs start, as a cut cable would: for
    /// trying the master's heartbeat watch.
    pub silent_node: Option<SilentNode>,
    /// On the virtual CAN bus: the valve's spool sticks where it is this
    /// long after the ECUs start (dirt, a broken pilot stage), while the
    /// valve goes on reporting its position: for trying the master's spool
    /// watch.
    pub stuck_spool: Option<StuckSpool>,
    /// One of its effects changes while it runs, as a wearing valve does:
    /// for trying the shadow model's drift detection.
    pub drift: Option<hydractl_plant::DriftSpec>,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SilentNode {
    pub node: u8,
    pub after_s: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StuckSpool {
    pub after_s: f64,
}

/// How deep `base = "FILE"` may chain.
const MAX_BASE_DEPTH: usize = 4;

impl Config {
    /// The load's model the loop's observer runs: the `[plant]` the config
    /// takes the machine to be.
    pub fn load_model(&self) -> LoadModel {
        LoadModel {
            inertia: self.plant.inertia,
            viscous_friction: self.plant.viscous_friction,
        }
    }

    /// Loads a config file. A file may start from another with
    /// `base = "OTHER.toml"` (relative to itself) and give only what
    /// differs: its tables are merged over the base's, key by key.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
            path: path.to_owned(),
            source,
        })?;
        if !text.lines().any(|l| l.trim_start().starts_with("base")) {
            return Ok(Self::parse(&text, path)?.resolved_from(path));
        }
        let table = Self::load_table(path, &text, 0)?;
        let config = Config::deserialize(toml::Value::Table(table)).map_err(|e| ConfigError::Parse {
            path: path.to_owned(),
            message: e.to_string(),
        })?;
        config.validate(path)?;
        // Each file's paths were made its own as it was read.
        Ok(config)
    }

    /// Paths in the file are the file's: relative to its folder.
    fn resolved_from(mut self, path: &Path) -> Self {
        let folder = path.parent().unwrap_or(Path::new("."));
        for file in [&mut self.shadow.model, &mut self.shadow.learned] {
            if let Some(file) = file.as_mut().filter(|m| m.is_relative()) {
                *file = folder.join(&*file);
            }
        }
        self
    }

    fn load_table(path: &Path, text: &str, depth: usize) -> Result<toml::Table, ConfigError> {
        let parse_error = |message: String| ConfigError::Parse {
            path: path.to_owned(),
            message,
        };
        let mut table: toml::Table = toml::from_str(text).map_err(|e| parse_error(e.to_string()))?;
        // A file's paths are its own, also when another file takes it as
        // its base from another folder.
        if let Some(shadow) = table.get_mut("shadow").and_then(toml::Value::as_table_mut) {
            for key in ["model", "learned"] {
                if let Some(toml::Value::String(file)) = shadow.get_mut(key) {
                    if Path::new(file.as_str()).is_relative() {
                        let resolved = path.parent().unwrap_or(Path::new(".")).join(&*file);
                        *file = resolved.display().to_string();
                    }
                }
            }
        }
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
        let base_text = std::fs::read_to_string(&base_path).map_err(|source| ConfigError::Base {
            path: path.to_owned(),
            base: base.to_owned(),
            resolved: base_path.clone(),
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
}

pub(crate) const DEFAULT_SIM_TOML: &str = include_str!("../../../config/sim.toml");

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
    fn a_swap_judge_that_would_undo_an_equal_variant_is_refused_by_name() {
        let path = Path::new("judge.toml");
        let sim = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/sim.toml"))
            .expect("config/sim.toml");
        assert_eq!(
            Config::parse(&sim, path).expect("sim.toml").supervisor.swap_judge_ms,
            2000
        );
        for (from, to, key) in [
            (
                "swap_rollback_factor = 2.0",
                "swap_rollback_factor = 0.5",
                "swap_rollback_factor",
            ),
            (
                "swap_rollback_min_rms_rad = 0.1",
                "swap_rollback_min_rms_rad = -1.0",
                "swap_rollback_min_rms_rad",
            ),
        ] {
            let err = Config::parse(&sim.replace(from, to), path).expect_err(key).to_string();
            assert!(err.contains(key) && err.contains("judge.toml"), "{err}");
        }
        let off = Config::parse(&sim.replace("swap_judge_ms = 2000", "swap_judge_ms = 0"), path).expect("not judged");
        assert_eq!(off.supervisor.swap_judge_ms, 0);
    }

    #[test]
    fn only_a_controller_designed_for_this_machine_may_be_a_fallback() {
        let path = Path::new("fallback.toml");
        let sim = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/sim.toml"))
            .expect("config/sim.toml");
        let hinf_fallback = sim.replace("fallback_variants = {}", "fallback_variants = { torque = \"hinf\" }");
        Config::parse(&hinf_fallback, path).expect("sim.toml's H∞ was designed for its plant");
        // The crane paper's controller: no design record.
        let start = hinf_fallback.find("[control.torque.hinf]").expect("hinf table");
        let end = hinf_fallback.find("[control.valve_guard]").expect("next table");
        let paper = format!(
            "{}[control.torque.hinf]\nerror_scale = 782.0\n\n{}",
            &hinf_fallback[..start],
            &hinf_fallback[end..]
        );
        let err = Config::parse(&paper, path)
            .expect_err("the paper's controller")
            .to_string();
        assert!(
            err.contains("fallback.toml") && err.contains("fallback_variants.torque") && err.contains("ident hinf"),
            "{err}"
        );
        // A design record whose controller does not hold its own plant model.
        let mismatched = hinf_fallback.replace("plant_num = [", "plant_num = [-");
        let err = Config::parse(&mismatched, path)
            .expect_err("unstable around its model")
            .to_string();
        assert!(err.contains("unstable"), "{err}");
        // The designed controller with its error scaled past its gain
        // margin (6.6 dB, 2.1×): not the controller that was designed.
        let scaled = hinf_fallback.replace("\nerror_scale = 1.0", "\nerror_scale = 3.0");
        let err = Config::parse(&scaled, path)
            .expect_err("unstable with its scale")
            .to_string();
        assert!(err.contains("unstable") && err.contains("error_scale 3"), "{err}");
        // Scaled within the margin it still holds its model.
        Config::parse(
            &hinf_fallback.replace("\nerror_scale = 1.0", "\nerror_scale = 1.5"),
            path,
        )
        .expect("within the gain margin");
    }

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
        assert!(
            err.contains("missing.toml") && err.contains("`base") && err.contains("bad.toml"),
            "names the key, the file that holds it and the file it could not read: {err}"
        );
        std::fs::remove_dir_all(dir).ok();
    }

    #[test]
    fn a_drifting_machine_and_its_shadow_load_and_their_mistakes_are_named() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/machine-drift.toml");
        let config = Config::load(&path).expect("config/machine-drift.toml");
        let model = config.shadow.model.as_deref().expect("a shadow model");
        assert!(model.is_file(), "resolved beside the config: {}", model.display());
        // As the README runs it: a path relative to the working folder
        // (the package's, under cargo test), its model resolved once.
        let relative = Config::load(Path::new("../../config/machine-drift.toml")).expect("relative");
        let model = relative.shadow.model.expect("a shadow model");
        assert_eq!(model, Path::new("../../config/machine-model.toml"));
        assert_eq!(config.machine.and_then(|m| m.drift).map(|d| d.to), Some(0.06));
        let cold = Config::load(&path.with_file_name("machine-cold.toml")).expect("config/machine-cold.toml");
        let drift = cold.machine.and_then(|m| m.drift).expect("a drift");
        assert_eq!((drift.effect.as_str(), drift.to), ("coulomb_friction", 80.0));

        let dir = std::env::temp_dir().join(format!("hydractl-shadow-config-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("dir");
        // Taken as a base from another folder, its model is still its own.
        let elsewhere = dir.join("elsewhere.toml");
        let text = format!(
            "base = {:?}\n[shadow]\nlearned = 'learned.toml'\n",
            path.display().to_string()
        );
        std::fs::write(&elsewhere, text).expect("write");
        let shadow = Config::load(&elsewhere).expect("elsewhere").shadow;
        assert!(shadow.model.as_deref().is_some_and(Path::is_file), "{:?}", shadow.model);
        assert_eq!(shadow.learned, Some(dir.join("learned.toml")));
        let bad = dir.join("bad.toml");
        let err = |text: &str| {
            std::fs::write(&bad, format!("base = {:?}\n{text}", path.display().to_string())).expect("write");
            Config::load(&bad).expect_err(text).to_string()
        };
        let said = err("[shadow]\nwindow_s = 2.0\n");
        assert!(said.contains("[shadow]") && said.contains("4 s"), "{said}");
        let said = err("[shadow]\nevery_s = 0.7\n");
        assert!(said.contains("every_s") && said.contains("0.5 s"), "{said}");
        let said = err("[machine.drift]\nkey = 'widht'\n");
        assert!(said.contains("machine.drift") && said.contains("widht"), "{said}");
        let said = err("[machine.drift]\neffect = 'time_delay'\nkey = 'delay_s'\n");
        assert!(said.contains("machine.drift") && said.contains("structure"), "{said}");
        std::fs::remove_dir_all(dir).ok();
    }

    #[test]
    fn built_in_default_parses() {
        let c = Config::parse(DEFAULT_SIM_TOML, Path::new("config/sim.toml")).expect("valid");
        assert_eq!(c.timing.substeps(), 10);
        assert!(c.effects.0.is_empty(), "the default plant has no effects");
    }

    #[test]
    fn a_can_table_the_loop_cannot_keep_is_named() {
        let ok = format!("{DEFAULT_SIM_TOML}\n[can]\n");
        Config::parse(&ok, Path::new("x.toml")).expect("the defaults fit");
        let late = format!("{DEFAULT_SIM_TOML}\n[can]\npdo_deadline_us = 950\n");
        let e = Config::parse(&late, Path::new("x.toml")).expect_err("no time to answer");
        assert!(e.to_string().contains("pdo_deadline_us = 950"), "{e}");
        // Three of the valve process's 5 ms ticks (a 20 ms silence timeout).
        let short = format!("{DEFAULT_SIM_TOML}\n[can.valve]\nrpdo_timeout_ms = 14\n");
        let e = Config::parse(&short, Path::new("x.toml")).expect_err("shorter than three ticks");
        assert!(e.to_string().contains("rpdo_timeout_ms = 14"), "{e}");
        assert!(e.to_string().contains("three ticks"), "{e}");
        let three = format!("{DEFAULT_SIM_TOML}\n[can.valve]\nrpdo_timeout_ms = 15\n");
        Config::parse(&three, Path::new("x.toml")).expect("three ticks are enough");
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

    #[test]
    fn a_controller_no_stage_accepts_is_named_by_its_section_at_load() {
        let bad = DEFAULT_SIM_TOML.replace("max_age_periods = 3 ", "max_age_periods = 0 ");
        let err = Config::parse(&bad, Path::new("x.toml")).expect_err("a guard of 0 periods");
        let text = err.to_string();
        assert!(
            text.contains("x.toml") && text.contains("[control.valve_guard]") && text.contains("max_age_periods"),
            "{text}"
        );
    }

    #[test]
    fn an_observer_the_loop_cannot_run_is_named_at_load() {
        let observer = DEFAULT_SIM_TOML.replace("method = \"differentiator\"", "method = \"observer\"");
        Config::parse(&observer, Path::new("x.toml")).expect("the observer at 80 rad/s");
        let bad = observer.replace("observer_bandwidth_rad_s = 80.0", "observer_bandwidth_rad_s = 1000.0");
        let text = Config::parse(&bad, Path::new("x.toml"))
            .expect_err("faster than a tenth of the loop")
            .to_string();
        assert!(
            text.contains("x.toml")
                && text.contains("[control.velocity_estimator]")
                && text.contains("observer_bandwidth_rad_s"),
            "{text}"
        );
    }
}
