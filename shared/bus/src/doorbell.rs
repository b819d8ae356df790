//! How a loop service's sample wakes the stage waiting for it: a futex in
//! the run's shared memory, the service's doorbell. A publisher rings it
//! after each sample (an atomic increment, and one `futex` wake only when
//! someone sleeps); a stage sleeps in one `futex` wait, with a timeout when
//! it has a clock of its own. iceoryx2's events wake a listener with a
//! datagram on a unix socket (a send, a `ppoll`, two receives: about 7 µs
//! a hop here); its semaphore events cannot be waited on with a timeout
//! without polling. The samples themselves still go through iceoryx2.
//!
//! The doorbell is two words in a file of the run's (`/dev/shm/<prefix>
//! doorbell.<service>`, owner only, removed with the run's other files):
//! the rings so far, and how many wait. Any process that opens it first
//! creates it; a stage that restarts opens it again and misses nothing,
//! since it reads every waiting sample on waking.

use std::fs::{File, OpenOptions};
use std::os::unix::fs::OpenOptionsExt;
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::Duration;

use linux_futex::{AsFutex, Shared, TimedWaitError};
use memmap2::MmapMut;

use crate::{BusError, RunScope};

/// The two words, and a full cache line so that nothing else shares it.
const SIZE: u64 = 64;

/// What ended a wait.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Rung {
    /// Rung at least once since the last wait.
    Yes,
    /// The timeout passed first.
    TimedOut,
    /// A signal came: the caller looks whether it ends the run.
    Interrupted,
}

/// A service's doorbell, mapped into this process.
pub struct Doorbell {
    map: MmapMut,
    /// The ring count this process last saw, as a waiter.
    seen: std::cell::Cell<u32>,
    path: std::path::PathBuf,
}

impl Doorbell {
    /// Opens the doorbell of `service` in `scope`, creating it if no one
    /// has yet.
    pub fn open(scope: &RunScope, service: &str) -> Result<Self, BusError> {
        let path = std::path::PathBuf::from(format!(
            "/dev/shm/{}doorbell.{}",
            scope.prefix(),
            service.replace('/', ".")
        ));
        let failed = |source: std::io::Error| {
            scope.permission_problem().unwrap_or_else(|| BusError::Doorbell {
                path: path.display().to_string(),
                source,
            })
        };
        let file: File = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            // Another process may have it open and ringing: never emptied.
            .truncate(false)
            .mode(0o600)
            .open(&path)
            .map_err(failed)?;
        // Two openers may both extend it: to the same size, zeroed.
        if file.metadata().map_err(failed)?.len() < SIZE {
            file.set_len(SIZE).map_err(failed)?;
        }
        // SAFETY: the mapping is shared with other processes by design and
        // only ever read and written through the atomics below; the file is
        // never shrunk while the run lives.
        #[allow(unsafe_code)]
        let map = unsafe { memmap2::MmapOptions::new().len(SIZE as usize).map_mut(&file) }.map_err(failed)?;
        let bell = Self {
            map,
            seen: std::cell::Cell::new(0),
            path,
        };
        bell.seen.set(bell.rings().load(Ordering::SeqCst));
        Ok(bell)
    }

    fn word(&self, index: usize) -> &AtomicU32 {
        let bytes = &self.map[index * 4..index * 4 + 4];
        // SAFETY: the mapping is page-aligned and 64 bytes long, so words 0
        // and 1 are aligned and in bounds; every process touches them only
        // as atomics; the reference lives no longer than the mapping.
        #[allow(unsafe_code)]
        unsafe {
            &*(bytes.as_ptr() as *const AtomicU32)
        }
    }

    /// The rings so far: the futex word.
    fn rings(&self) -> &AtomicU32 {
        self.word(0)
    }

    /// How many processes sleep on it now.
    fn sleepers(&self) -> &AtomicU32 {
        self.word(1)
    }

    /// Wakes every process waiting on this doorbell. No system call when
    /// none sleeps.
    pub fn ring(&self) {
        self.rings().fetch_add(1, Ordering::SeqCst);
        if self.sleepers().load(Ordering::SeqCst) > 0 {
            AsFutex::<Shared>::as_futex(self.rings()).wake(i32::MAX);
        }
    }

    /// Sleeps until the doorbell rings (at once if it rang since the last
    /// wait), `timeout` passes, or a signal comes.
    pub fn wait(&self, timeout: Duration) -> Rung {
        let rings = self.rings();
        let seen = self.seen.get();
        let now = rings.load(Ordering::SeqCst);
        if now != seen {
            self.seen.set(now);
            return Rung::Yes;
        }
        // Counted as a sleeper before the last look: a ring after it either
        // changes the word (the wait returns at once) or sees the sleeper
        // and wakes it.
        self.sleepers().fetch_add(1, Ordering::SeqCst);
        let outcome = match AsFutex::<Shared>::as_futex(rings).wait_for(seen, timeout) {
            Ok(()) | Err(TimedWaitError::WrongValue) => None,
            Err(TimedWaitError::TimedOut) => Some(Rung::TimedOut),
            Err(TimedWaitError::Interrupted) => Some(Rung::Interrupted),
        };
        self.sleepers().fetch_sub(1, Ordering::SeqCst);
        let now = rings.load(Ordering::SeqCst);
        if now != seen {
            self.seen.set(now);
            return Rung::Yes;
        }
        // Woken with nothing new (another waiter's ring was taken, a
        // spurious wake-up): a timeout or signal is said as such.
        outcome.unwrap_or(Rung::TimedOut)
    }

    /// Forgets the rings so far: the next wait sleeps until a new one.
    pub fn clear(&self) {
        self.seen.set(self.rings().load(Ordering::SeqCst));
    }

    pub fn path(&self) -> &std::path::Path {
        &self.path
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scope(name: &str) -> RunScope {
        let scope = RunScope::new(&format!("dbt{}{name}_", std::process::id() % 100_000)).expect("scope");
        scope.remove_all_files().expect("clean");
        scope
    }

    #[test]
    fn a_ring_before_the_wait_is_not_lost_and_is_taken_once() {
        let scope = scope("a");
        let publisher = Doorbell::open(&scope, "hydractl/test").expect("open");
        let waiter = Doorbell::open(&scope, "hydractl/test").expect("open");
        publisher.ring();
        publisher.ring();
        assert_eq!(waiter.wait(Duration::from_millis(1)), Rung::Yes);
        assert_eq!(waiter.wait(Duration::from_millis(1)), Rung::TimedOut);
        scope.remove_all_files().expect("clean");
    }

    #[test]
    fn a_sleeping_waiter_is_woken_by_a_ring_from_another_thread() {
        let scope = scope("b");
        let waiter = Doorbell::open(&scope, "hydractl/test").expect("open");
        let ringing = {
            let scope = scope.clone();
            std::thread::spawn(move || {
                let publisher = Doorbell::open(&scope, "hydractl/test").expect("open");
                std::thread::sleep(Duration::from_millis(20));
                publisher.ring();
            })
        };
        let started = std::time::Instant::now();
        assert_eq!(waiter.wait(Duration::from_secs(5)), Rung::Yes);
        assert!(
            started.elapsed() < Duration::from_secs(4),
            "woken by the ring, not the timeout"
        );
        ringing.join().expect("ringer");
        assert_eq!(waiter.sleepers().load(Ordering::SeqCst), 0);
        scope.remove_all_files().expect("clean");
    }

    #[test]
    fn every_waiter_is_woken_and_a_cleared_ring_is_forgotten() {
        let scope = scope("c");
        let publisher = Doorbell::open(&scope, "hydractl/test").expect("open");
        let first = Doorbell::open(&scope, "hydractl/test").expect("open");
        let second = Doorbell::open(&scope, "hydractl/test").expect("open");
        publisher.ring();
        assert_eq!(first.wait(Duration::ZERO), Rung::Yes);
        assert_eq!(second.wait(Duration::ZERO), Rung::Yes);
        publisher.ring();
        first.clear();
        assert_eq!(first.wait(Duration::from_millis(1)), Rung::TimedOut);
        assert!(first.path().starts_with("/dev/shm"));
        scope.remove_all_files().expect("clean");
        assert!(!scope.has_files());
    }
}
