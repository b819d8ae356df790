//! `[supervisor]`: how the supervisor watches, restarts and falls back.

use serde::{Deserialize, Serialize};

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
    /// How a controller whose commands limit-cycle comes back, when no
    /// fallback variant is given for its stage.
    pub on_limit_cycle: OnLimitCycle,
    /// `backoff`'s first wait, doubled at every limit cycle of the stage.
    pub limit_cycle_backoff_ms: u64,
    /// A loop process that takes more than this share of its CPU…
    pub spinning_cpu_share: f64,
    /// …for this long without a break spins (a busy loop starves every
    /// process on the loop's CPU): it is killed and restarted.
    pub spinning_after_ms: u64,
    /// After a swap, the tracking error is watched for this long (0: not
    /// at all) and compared with as long before it…
    pub swap_judge_ms: u64,
    /// …and a variant whose rms exceeds the previous one's this many times
    /// is swapped back…
    pub swap_rollback_factor: f64,
    /// …when its rms is above this too, rad: a loop tracking within noise
    /// stays whatever the ratio. A fault's restart into a fallback variant
    /// is judged the same way against the tracking before the fault, after…
    pub swap_rollback_min_rms_rad: f64,
    /// …this long from its first output: the load coming back after the
    /// valve was held neutral is not the variant's tracking.
    pub fallback_settle_ms: u64,
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
            on_limit_cycle: OnLimitCycle::Baseline,
            limit_cycle_backoff_ms: 1000,
            spinning_cpu_share: 0.5,
            spinning_after_ms: 20,
            swap_judge_ms: 2000,
            swap_rollback_factor: 2.0,
            swap_rollback_min_rms_rad: 0.1,
            fallback_settle_ms: 1000,
        }
    }
}

/// How a limit-cycling controller comes back: never into the same
/// behaviour without end.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum OnLimitCycle {
    /// Into the papers' baseline PID for its stage; when the PID itself
    /// limit-cycles, as `backoff`.
    #[default]
    Baseline,
    /// The same variant, after `limit_cycle_backoff_ms`, doubled at every
    /// limit cycle (the valve neutral meanwhile).
    Backoff,
    /// Left down: the valve stays neutral until someone acts.
    Stop,
}

/// The processes a supervisor's restart rules may name.
pub(crate) const SUPERVISED_PROCESSES: [&str; 9] = [
    "plant", "machine", "sensor", "friction", "position", "torque", "valve", "recorder", "shadow",
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
