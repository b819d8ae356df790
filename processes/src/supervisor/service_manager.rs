//! systemd's view of the run, when a unit started it (`Type=notify`,
//! `NotifyAccess=all`, `WatchdogSec=`): `READY=1` once the valve answers
//! the loop's readings, then `WATCHDOG=1` while the supervisor's rounds
//! go on. A supervisor that stops going round stops the pings, and
//! systemd stops the unit and starts it again.
//!
//! `hydractl run` is the unit's main process and the supervisor its child:
//! `WATCHDOG_PID` names the former, so the interval is read from
//! `WATCHDOG_USEC` alone. The loop's processes never inherit the socket.

use std::time::{Duration, Instant};

pub(crate) struct ServiceManager {
    /// A unit listens (`NOTIFY_SOCKET` is set).
    listening: bool,
    /// How often to ping: half the unit's `WatchdogSec`.
    ping_every: Option<Duration>,
    last_ping: Option<Instant>,
    ready: bool,
    /// A send failed: said once, not every round.
    failing: bool,
}

impl ServiceManager {
    pub(crate) fn from_env() -> Self {
        let watchdog = std::env::var("WATCHDOG_USEC")
            .ok()
            .and_then(|usec| usec.parse::<u64>().ok())
            .filter(|&usec| usec > 0)
            .map(Duration::from_micros);
        Self::new(std::env::var_os("NOTIFY_SOCKET").is_some(), watchdog)
    }

    fn new(listening: bool, watchdog: Option<Duration>) -> Self {
        Self {
            listening,
            ping_every: watchdog.map(|w| w / 2),
            last_ping: None,
            ready: false,
            failing: false,
        }
    }

    /// Whether `READY=1` is still to be said (the caller looks whether the
    /// loop answers only until then).
    pub(crate) fn awaits_ready(&self) -> bool {
        self.listening && !self.ready
    }

    /// One supervisor round: what to tell systemd now, if anything.
    fn due(&mut self, now: Instant, loop_answers: bool) -> Vec<sd_notify::NotifyState<'static>> {
        let mut states = Vec::new();
        if !self.listening {
            return states;
        }
        if !self.ready && loop_answers {
            self.ready = true;
            states.push(sd_notify::NotifyState::Ready);
            states.push(sd_notify::NotifyState::Status("the loop runs"));
        }
        if let Some(every) = self.ping_every {
            if self
                .last_ping
                .is_none_or(|at| now.saturating_duration_since(at) >= every)
            {
                self.last_ping = Some(now);
                states.push(sd_notify::NotifyState::Watchdog);
            }
        }
        states
    }

    /// Tells systemd what is due; a failure is said once, and the run goes
    /// on (systemd's own timeouts judge a supervisor it cannot hear).
    pub(crate) fn tick(&mut self, now: Instant, loop_answers: bool) {
        let states = self.due(now, loop_answers);
        if states.is_empty() {
            return;
        }
        match sd_notify::notify(&states) {
            Ok(()) => self.failing = false,
            Err(e) if !self.failing => {
                self.failing = true;
                tracing::warn!("cannot notify systemd (NOTIFY_SOCKET): {e}");
            }
            Err(_) => {}
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ready_once_the_loop_answers_then_a_ping_every_half_watchdog() {
        let t0 = Instant::now();
        let ms = |n: u64| t0 + Duration::from_millis(n);
        let mut manager = ServiceManager::new(true, Some(Duration::from_secs(2)));
        let names =
            |states: Vec<sd_notify::NotifyState<'static>>| states.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        assert_eq!(names(manager.due(ms(0), false)), ["WATCHDOG=1"]);
        assert!(manager.due(ms(5), false).is_empty());
        assert_eq!(names(manager.due(ms(10), true)), ["READY=1", "STATUS=the loop runs"]);
        assert!(manager.due(ms(995), true).is_empty());
        assert_eq!(names(manager.due(ms(1000), true)), ["WATCHDOG=1"]);
        // Without a unit listening, nothing is sent.
        let mut alone = ServiceManager::new(false, Some(Duration::from_secs(2)));
        assert!(alone.due(ms(0), true).is_empty());
    }
}
