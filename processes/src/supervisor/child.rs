//! The supervisor's bookkeeping of its children: spawning, reaping,
//! restart back-off, and stopping. OS process management, no control.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use hydractl_bus::{RunScope, PREFIX_ENV};
use hydractl_config::{RestartPolicy, SupervisorConfig};
use nix::sys::signal::{kill, Signal};
use nix::unistd::Pid;

/// The processes of the loop, in pipeline order, with the service each
/// publishes (its heartbeat) and the one it consumes: the one before its
/// own, and for the plant the valve's.
pub(crate) const PIPELINE: [(&str, &str, &str); 6] = {
    use hydractl_samples::service::{PIPELINE_PROCESSES, PIPELINE_SERVICES};
    let n = PIPELINE_PROCESSES.len();
    let mut pipeline = [("", "", ""); 6];
    let mut i = 0;
    while i < n {
        pipeline[i] = (
            PIPELINE_PROCESSES[i],
            PIPELINE_SERVICES[i],
            PIPELINE_SERVICES[(i + n - 1) % n],
        );
        i += 1;
    }
    pipeline
};

/// One supervised process.
#[derive(Debug)]
pub(crate) struct Supervised {
    pub name: &'static str,
    binary: PathBuf,
    config: Option<PathBuf>,
    /// The controller variant it runs (`--variant`), for position and torque.
    pub variant: Option<&'static str>,
    child: Option<Child>,
    pub pids: Vec<u32>,
    pub restarts: u32,
    started_at: Instant,
    /// When it was last spawned, on the samples' clock: an answer stamped
    /// before it came from the process it replaced.
    spawned_ns: u64,
    backoff: Duration,
    restart_at: Option<Instant>,
    /// Last time its output advanced.
    pub last_output: Instant,
    /// The last reading its output answered.
    pub last_seq: Option<u64>,
    /// How its last run ended: `true` for a clean exit (status 0).
    pub exited_cleanly: bool,
    /// Its restarts within the restart rule's window.
    restart_times: std::collections::VecDeque<Instant>,
    /// Why it is left down, when its restart rule says so.
    pub given_up: Option<String>,
    /// How many times its commands limit-cycled in this run.
    pub limit_cycles: u32,
    /// When its input last started flowing again after a pause: a hang is
    /// counted from here too, so a stage whose input was gone is not
    /// declared hung the moment the input returns.
    pub input_resumed: Instant,
}

impl Supervised {
    pub fn new(name: &'static str, process_dir: &Path, config: Option<PathBuf>) -> Self {
        let now = Instant::now();
        Self {
            name,
            binary: process_dir.join(name),
            config,
            variant: None,
            child: None,
            pids: Vec::new(),
            restarts: 0,
            started_at: now,
            spawned_ns: 0,
            backoff: Duration::ZERO,
            restart_at: None,
            last_output: now,
            last_seq: None,
            exited_cleanly: false,
            restart_times: std::collections::VecDeque::new(),
            given_up: None,
            limit_cycles: 0,
            input_resumed: now,
        }
    }

    pub fn pid(&self) -> Option<u32> {
        self.child.as_ref().map(Child::id)
    }

    pub fn is_running(&self) -> bool {
        self.child.is_some()
    }

    /// Whether an answer stamped `time_ns` came from the process running
    /// now: not from one it replaced, nor, while it is down, from the one
    /// just killed (a sample published before it died, read only later).
    pub fn answered_by_current(&self, time_ns: u64) -> bool {
        self.is_running() && time_ns >= self.spawned_ns
    }

    pub fn uptime(&self, now: Instant) -> Duration {
        now.saturating_duration_since(self.started_at)
    }

    pub fn spawn(&mut self, scope: &RunScope, extra_args: &[String]) -> Result<()> {
        let mut command = Command::new(&self.binary);
        if let Some(config) = &self.config {
            command.arg("--config").arg(config);
        }
        if let Some(variant) = self.variant {
            command.arg("--variant").arg(variant);
        }
        command.args(extra_args);
        // Stamped before it can publish: all its answers come after.
        let spawned_ns = hydractl_bus::clock::now_ns();
        let child = command
            .env(PREFIX_ENV, scope.prefix())
            // systemd hears from the supervisor alone (service_manager.rs).
            .env_remove("NOTIFY_SOCKET")
            .env_remove("WATCHDOG_USEC")
            .env_remove("WATCHDOG_PID")
            .stdin(Stdio::null())
            .spawn()
            .with_context(|| format!("starting {}", self.binary.display()))?;
        tracing::info!(
            child = self.name,
            child_pid = child.id(),
            variant = self.variant.unwrap_or(""),
            "started {} (pid {}){}",
            self.name,
            child.id(),
            self.variant.map_or(String::new(), |v| format!(" as {v}"))
        );
        self.pids.push(child.id());
        self.child = Some(child);
        let now = Instant::now();
        self.started_at = now;
        self.spawned_ns = spawned_ns;
        self.last_output = now;
        self.restart_at = None;
        Ok(())
    }

    /// Reaps the child if it exited; true when it did. An error from the
    /// wait says nothing about the child, so it counts as still running.
    pub fn reap(&mut self) -> bool {
        let status = match &mut self.child {
            Some(child) => child.try_wait().ok().flatten(),
            None => None,
        };
        if let Some(status) = status {
            self.exited_cleanly = status.success();
            self.child = None;
        }
        status.is_some()
    }

    /// Kills a hung child with SIGKILL and reaps it.
    pub fn kill_hung(&mut self) {
        if let Some(mut child) = self.child.take() {
            let _ = child.kill();
            let _ = child.wait();
        }
        self.exited_cleanly = false;
    }

    /// After it stopped: schedules a restart if its restart rule allows
    /// one, or leaves it down and says why (in [`Supervised::given_up`]).
    /// Returns whether a restart is scheduled.
    pub fn after_stop(&mut self, now: Instant, policy: &SupervisorConfig) -> bool {
        let rule = policy.restart_rule(self.name);
        let window = Duration::from_secs_f64(rule.window_s);
        while self
            .restart_times
            .front()
            .is_some_and(|&t| now.saturating_duration_since(t) > window)
        {
            self.restart_times.pop_front();
        }
        let refusal = match rule.policy {
            RestartPolicy::Never => Some("its restart policy is `never`".to_owned()),
            RestartPolicy::OnFailure if self.exited_cleanly => {
                Some("it exited cleanly and its restart policy is `on-failure`".to_owned())
            }
            _ if self.restart_times.len() >= rule.max_restarts as usize => Some(format!(
                "it was restarted {} times within {} s (max_restarts)",
                self.restart_times.len(),
                rule.window_s
            )),
            _ => None,
        };
        if let Some(why) = refusal {
            self.given_up = Some(why);
            self.restart_at = None;
            return false;
        }
        self.restart_times.push_back(now);
        self.schedule_restart(now, policy);
        true
    }

    /// Schedules a restart after the back-off, doubling it for next time
    /// unless the process had been up long enough to count as healthy.
    fn schedule_restart(&mut self, now: Instant, policy: &SupervisorConfig) {
        let initial = Duration::from_millis(policy.restart_backoff_initial_ms);
        let max = Duration::from_millis(policy.restart_backoff_max_ms);
        if self.uptime(now) >= Duration::from_millis(policy.healthy_after_ms) || self.backoff.is_zero() {
            self.backoff = initial;
        } else {
            self.backoff = (self.backoff * 2).min(max);
        }
        self.restart_at = Some(now + self.backoff);
    }

    /// Holds its scheduled restart until at least `at`.
    pub fn delay_restart(&mut self, at: Instant) {
        self.restart_at = self.restart_at.map(|scheduled| scheduled.max(at));
    }

    /// Leaves it down, for `why`.
    pub fn give_up(&mut self, why: String) {
        self.given_up = Some(why);
        self.restart_at = None;
    }

    pub fn restart_due(&self, now: Instant) -> bool {
        self.child.is_none() && self.restart_at.is_some_and(|at| now >= at)
    }

    /// Asks the child to stop (SIGTERM).
    pub fn request_stop(&self) {
        if let Some(child) = &self.child {
            let _ = kill(Pid::from_raw(child.id() as i32), Signal::SIGTERM);
        }
    }

    /// Waits for a stopping child until `deadline`, then kills it.
    pub fn finish_stop(&mut self, deadline: Instant) {
        if let Some(mut child) = self.child.take() {
            while Instant::now() < deadline {
                if matches!(child.try_wait(), Ok(Some(_))) {
                    return;
                }
                std::thread::sleep(Duration::from_millis(2));
            }
            let _ = child.kill();
            let _ = child.wait();
        }
    }
}

/// A supervisor that unwinds (an error, a panic) must not leave its
/// children running.
impl Drop for Supervised {
    fn drop(&mut self) {
        if let Some(mut child) = self.child.take() {
            let _ = child.kill();
            let _ = child.wait();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_process_of_the_pipeline_consumes_what_the_one_before_publishes() {
        use hydractl_samples::service::{FRICTION, PLANT_READING, POSITION, SENSOR, TORQUE, VALVE};
        assert_eq!(
            PIPELINE,
            [
                ("plant", PLANT_READING, VALVE),
                ("sensor", SENSOR, PLANT_READING),
                ("friction", FRICTION, SENSOR),
                ("position", POSITION, FRICTION),
                ("torque", TORQUE, POSITION),
                ("valve", VALVE, TORQUE),
            ]
        );
    }

    #[test]
    fn backoff_doubles_up_to_the_limit_and_resets_when_healthy() {
        let policy = SupervisorConfig {
            restart_backoff_initial_ms: 10,
            restart_backoff_max_ms: 35,
            healthy_after_ms: 1000,
            ..SupervisorConfig::default()
        };
        let mut s = Supervised::new("x", Path::new("/nonexistent"), None);
        let now = s.started_at;
        s.schedule_restart(now, &policy);
        assert_eq!(s.backoff, Duration::from_millis(10));
        s.schedule_restart(now, &policy);
        assert_eq!(s.backoff, Duration::from_millis(20));
        s.schedule_restart(now, &policy);
        assert_eq!(s.backoff, Duration::from_millis(35));
        s.schedule_restart(now + Duration::from_secs(2), &policy);
        assert_eq!(s.backoff, Duration::from_millis(10));
        assert!(!s.restart_due(now));
        assert!(s.restart_due(now + Duration::from_secs(3)));
    }

    #[test]
    fn while_it_is_down_no_answer_is_its_successors() {
        let never_started = Supervised::new("torque", Path::new("/nonexistent"), None);
        assert!(!never_started.answered_by_current(u64::MAX));
        let scope = RunScope::new("childtest").expect("scope");
        let mut s = Supervised::new("sleep", Path::new("/bin"), None);
        let before_spawn = hydractl_bus::clock::now_ns();
        s.spawn(&scope, &["30".to_owned()]).expect("sleep starts");
        let last_answer = hydractl_bus::clock::now_ns();
        assert!(s.answered_by_current(last_answer));
        assert!(!s.answered_by_current(before_spawn), "its predecessor's");
        s.kill_hung();
        // Its last sample, read only after it was killed, during its back-off.
        assert!(!s.answered_by_current(last_answer));
        s.spawn(&scope, &["30".to_owned()]).expect("sleep starts again");
        assert!(
            !s.answered_by_current(last_answer),
            "the killed one's, not the successor's"
        );
        assert!(s.answered_by_current(hydractl_bus::clock::now_ns()));
        s.kill_hung();
    }

    #[test]
    fn restart_rules_refuse_and_say_why() {
        let mut policy = SupervisorConfig::default();
        policy.restart.max_restarts = 2;
        policy.restart.window_s = 10.0;
        policy.processes.insert(
            "valve".into(),
            hydractl_config::RestartRule {
                policy: RestartPolicy::OnFailure,
                ..hydractl_config::RestartRule::default()
            },
        );
        policy.processes.insert(
            "plant".into(),
            hydractl_config::RestartRule {
                policy: RestartPolicy::Never,
                ..hydractl_config::RestartRule::default()
            },
        );
        let mut friction = Supervised::new("friction", Path::new("/nonexistent"), None);
        let now = friction.started_at;
        assert!(friction.after_stop(now, &policy));
        assert!(friction.after_stop(now + Duration::from_secs(1), &policy));
        assert!(
            !friction.after_stop(now + Duration::from_secs(2), &policy),
            "a third within 10 s"
        );
        assert!(friction.given_up.as_deref().is_some_and(|w| w.contains("max_restarts")));
        let mut friction = Supervised::new("friction", Path::new("/nonexistent"), None);
        assert!(friction.after_stop(now, &policy));
        assert!(friction.after_stop(now + Duration::from_secs(1), &policy));
        assert!(
            friction.after_stop(now + Duration::from_secs(12), &policy),
            "the window has moved on"
        );

        let mut valve = Supervised::new("valve", Path::new("/nonexistent"), None);
        valve.exited_cleanly = true;
        assert!(!valve.after_stop(now, &policy));
        valve.exited_cleanly = false;
        valve.given_up = None;
        assert!(valve.after_stop(now, &policy), "a crash is a failure");

        let mut plant = Supervised::new("plant", Path::new("/nonexistent"), None);
        assert!(!plant.after_stop(now, &policy));
        assert!(plant.given_up.as_deref().is_some_and(|w| w.contains("never")));
    }
}
