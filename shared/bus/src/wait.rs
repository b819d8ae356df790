use std::time::Duration;

use iceoryx2::port::listener::Listener;
use iceoryx2::prelude::*;

use crate::BusError;

/// What woke the loop.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Wake {
    /// A sample arrived on input `i` (its events are already drained).
    Input(usize),
    /// The periodic tick.
    Tick,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Flow {
    Continue,
    Stop,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LoopExit {
    /// SIGINT or SIGTERM.
    Signal,
    /// The callback asked to stop.
    Stopped,
}

/// Sleeps until one of `inputs` is notified or the optional `tick` passes,
/// and calls `on_wake` for each; returns on SIGINT or SIGTERM or when
/// `on_wake` stops. No busy loop: the process sleeps in the kernel between
/// events.
///
/// It sleeps in `ppoll(2)` on the listeners' sockets, then takes each
/// notification with the listener's non-blocking wait: three system calls
/// per wake-up. The listener's own blocking wait costs seven (it switches
/// the socket to blocking mode and sets its timeout before each receive,
/// then back to non-blocking to drain it; counted with `strace -c`), and a
/// WaitSet adds an epoll round. SIGINT and SIGTERM are blocked while the
/// callback runs and let through only inside `ppoll`, so a signal that comes
/// mid-cycle ends the next wait at once instead of being missed.
pub fn run_loop(
    inputs: &[&Listener<ipc::Service>],
    tick: Option<Duration>,
    bus: &crate::Bus,
    mut on_wake: impl FnMut(Wake) -> Flow,
) -> Result<LoopExit, BusError> {
    use nix::errno::Errno;
    use nix::poll::{ppoll, PollFd, PollFlags};
    use nix::sys::signal::{SigSet, SigmaskHow, Signal};
    use nix::sys::time::TimeSpec;
    use std::time::Instant;

    let mut fds: Vec<PollFd> = inputs
        .iter()
        .map(|listener| PollFd::new(listener_fd(listener), PollFlags::POLLIN))
        .collect();
    let mut terminating = SigSet::empty();
    terminating.add(Signal::SIGINT);
    terminating.add(Signal::SIGTERM);
    let mut outside_wait = SigSet::empty();
    nix::sys::signal::pthread_sigmask(SigmaskHow::SIG_BLOCK, Some(&terminating), Some(&mut outside_wait))
        .map_err(|e| BusError::ipc("blocking SIGINT and SIGTERM outside the wait", e))?;
    // Inside the wait, the mask the thread had, less the two.
    let mut inside_wait = outside_wait;
    inside_wait.remove(Signal::SIGINT);
    inside_wait.remove(Signal::SIGTERM);
    let mut next_tick = tick.map(|period| Instant::now() + period);
    // A signal that came before the mask (during start-up) was taken by
    // iceoryx2's handler then, and will not interrupt the wait below.
    if bus.termination_requested() {
        nix::sys::signal::pthread_sigmask(SigmaskHow::SIG_SETMASK, Some(&outside_wait), None)
            .map_err(|e| BusError::ipc("restoring the signal mask", e))?;
        return Ok(LoopExit::Signal);
    }
    let result = (|| loop {
        let timeout = next_tick.map(|at| TimeSpec::from_duration(at.saturating_duration_since(Instant::now())));
        match ppoll(&mut fds, timeout, Some(inside_wait)) {
            Ok(_) => {}
            Err(Errno::EINTR) => {
                if bus.termination_requested() {
                    return Ok(LoopExit::Signal);
                }
                continue;
            }
            Err(e) => return Err(BusError::ipc("waiting on the inputs", e)),
        }
        for (i, fd) in fds.iter().enumerate() {
            let Some(events) = fd.revents() else { continue };
            if events.intersects(PollFlags::POLLERR | PollFlags::POLLNVAL) {
                return Err(BusError::ipc("waiting on the inputs", events));
            }
            if !events.contains(PollFlags::POLLIN) {
                continue;
            }
            let notified = inputs[i]
                .try_wait(|_| {})
                .map_err(|e| BusError::ipc("taking an input's notification", e))?;
            if notified > 0 && on_wake(Wake::Input(i)) == Flow::Stop {
                return Ok(LoopExit::Stopped);
            }
        }
        if let (Some(at), Some(period)) = (next_tick, tick) {
            let now = Instant::now();
            if now >= at {
                // A late tick is not made up for: the next is a period on.
                next_tick = Some((at + period).max(now));
                if on_wake(Wake::Tick) == Flow::Stop {
                    return Ok(LoopExit::Stopped);
                }
            }
        }
    })();
    nix::sys::signal::pthread_sigmask(SigmaskHow::SIG_SETMASK, Some(&outside_wait), None)
        .map_err(|e| BusError::ipc("restoring the signal mask", e))?;
    result
}

/// Runs one step inside a loop callback: an error stops the loop and is
/// kept for the caller to return once the loop is over.
pub fn guarded<E>(failure: &mut Option<E>, step: impl FnOnce() -> Result<(), E>) -> Flow {
    match step() {
        Ok(()) => Flow::Continue,
        Err(e) => {
            *failure = Some(e);
            Flow::Stop
        }
    }
}

/// The socket a listener's notifications arrive on, to poll. iceoryx2 keeps
/// the descriptor for the listener's lifetime, and it is never closed here.
fn listener_fd(listener: &Listener<ipc::Service>) -> std::os::fd::BorrowedFd<'_> {
    // SAFETY: the descriptor is open for as long as `listener` lives, which
    // the returned borrow cannot outlive.
    #[allow(unsafe_code)]
    unsafe {
        std::os::fd::BorrowedFd::borrow_raw(listener.file_descriptor().native_handle())
    }
}

/// The loop of a stage with one input and no tick.
pub fn run_single(
    listener: &Listener<ipc::Service>,
    bus: &crate::Bus,
    mut on_input: impl FnMut() -> Flow,
) -> Result<LoopExit, BusError> {
    run_loop(&[listener], None, bus, |_| on_input())
}
