use std::time::{Duration, Instant};

use iceoryx2::port::listener::Listener;
use iceoryx2::prelude::*;

use crate::{BusError, Doorbell, Rung};

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
    on_wake: impl FnMut(Wake) -> Flow,
) -> Result<LoopExit, BusError> {
    let inputs: Vec<Input<'_>> = inputs.iter().map(|&listener| Input::Listener(listener)).collect();
    let mut next_tick = tick.map(|period| Instant::now() + period);
    let timer = move |now: Option<Instant>| match (now, tick) {
        // A late tick is not made up for: the next is a period on.
        (Some(now), Some(period)) => {
            next_tick = next_tick.map(|at| (at + period).max(now));
            next_tick
        }
        _ => next_tick,
    };
    wait_loop(&inputs, bus, timer, on_wake)
}

/// What a loop sleeps on: an iceoryx2 listener (its notifications are
/// taken before the callback runs), a socket (a CAN socket; the callback
/// reads it until it would block), or a doorbell (a futex: the loop's
/// fastest hop, waited on alone, since no `ppoll` sees it).
#[derive(Clone, Copy)]
pub enum Input<'a> {
    Listener(&'a Listener<ipc::Service>),
    Socket(std::os::fd::BorrowedFd<'a>),
    Doorbell(&'a Doorbell),
}

/// [`run_loop`] with a deadline instead of a period: `next_deadline` is
/// asked before every wait, and the callback gets [`Wake::Tick`] once it
/// has passed.
pub fn run_until(
    inputs: &[Input<'_>],
    bus: &crate::Bus,
    mut next_deadline: impl FnMut() -> Option<Instant>,
    on_wake: impl FnMut(Wake) -> Flow,
) -> Result<LoopExit, BusError> {
    wait_loop(inputs, bus, move |_| next_deadline(), on_wake)
}

/// The one loop: `timer(None)` gives the next deadline; `timer(Some(now))`
/// is called after a deadline fired and gives the next.
fn wait_loop(
    inputs: &[Input<'_>],
    bus: &crate::Bus,
    mut timer: impl FnMut(Option<Instant>) -> Option<Instant>,
    mut on_wake: impl FnMut(Wake) -> Flow,
) -> Result<LoopExit, BusError> {
    use nix::errno::Errno;
    use nix::poll::{ppoll, PollFd, PollFlags};
    use nix::sys::signal::{SigSet, SigmaskHow, Signal};
    use nix::sys::time::TimeSpec;

    if let [Input::Doorbell(bell)] = inputs {
        return doorbell_loop(bell, timer, on_wake);
    }
    let mut fds: Vec<PollFd> = inputs
        .iter()
        .map(|input| match input {
            Input::Listener(listener) => Ok(PollFd::new(listener_fd(listener), PollFlags::POLLIN)),
            Input::Socket(fd) => Ok(PollFd::new(*fd, PollFlags::POLLIN)),
            Input::Doorbell(_) => Err(BusError::ipc(
                "waiting on the inputs",
                "a doorbell is waited on alone, not beside other inputs",
            )),
        })
        .collect::<Result<_, _>>()?;
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
    let mut deadline = timer(None);
    // A signal that came before the mask (during start-up) was taken by
    // iceoryx2's handler then, and will not interrupt the wait below.
    if bus.termination_requested() {
        nix::sys::signal::pthread_sigmask(SigmaskHow::SIG_SETMASK, Some(&outside_wait), None)
            .map_err(|e| BusError::ipc("restoring the signal mask", e))?;
        return Ok(LoopExit::Signal);
    }
    let result = (|| loop {
        let timeout = deadline.map(|at| TimeSpec::from_duration(at.saturating_duration_since(Instant::now())));
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
            let notified = match inputs[i] {
                Input::Listener(listener) => listener
                    .try_wait(|_| {})
                    .map_err(|e| BusError::ipc("taking an input's notification", e))?,
                Input::Socket(_) | Input::Doorbell(_) => 1,
            };
            if notified > 0 && on_wake(Wake::Input(i)) == Flow::Stop {
                return Ok(LoopExit::Stopped);
            }
        }
        match tick_if_due(deadline, &mut timer, &mut on_wake) {
            Some(next) => deadline = next,
            None => return Ok(LoopExit::Stopped),
        }
    })();
    nix::sys::signal::pthread_sigmask(SigmaskHow::SIG_SETMASK, Some(&outside_wait), None)
        .map_err(|e| BusError::ipc("restoring the signal mask", e))?;
    result
}

/// The longest a doorbell's wait sleeps without a deadline. A signal ends
/// a timed futex wait, while an untimed one is restarted under iceoryx2's
/// `SA_RESTART` handler: every wait is timed, so a SIGTERM is seen at once,
/// and within this bound if it came between the last look and the wait.
const LONGEST_DOORBELL_SLEEP: Duration = Duration::from_millis(200);

/// [`wait_loop`] on a doorbell: one futex wait per wake-up, no system call
/// to look at the signals (iceoryx2's handler sets a flag).
fn doorbell_loop(
    bell: &Doorbell,
    mut timer: impl FnMut(Option<Instant>) -> Option<Instant>,
    mut on_wake: impl FnMut(Wake) -> Flow,
) -> Result<LoopExit, BusError> {
    use iceoryx2_bb_posix::signal::SignalHandler;
    // A futex wait has no signal mask of its own, as `ppoll` has.
    unblock_termination_signals()?;
    let mut deadline = timer(None);
    loop {
        if SignalHandler::termination_requested() {
            return Ok(LoopExit::Signal);
        }
        let timeout = deadline.map_or(LONGEST_DOORBELL_SLEEP, |at| {
            at.saturating_duration_since(Instant::now()).min(LONGEST_DOORBELL_SLEEP)
        });
        if bell.wait(timeout) == Rung::Yes && on_wake(Wake::Input(0)) == Flow::Stop {
            return Ok(LoopExit::Stopped);
        }
        match tick_if_due(deadline, &mut timer, &mut on_wake) {
            Some(next) => deadline = next,
            None => return Ok(LoopExit::Stopped),
        }
    }
}

/// After a wait: the tick, when `deadline` has passed. The next deadline,
/// or `None` when the callback stopped the loop.
fn tick_if_due(
    deadline: Option<Instant>,
    timer: &mut impl FnMut(Option<Instant>) -> Option<Instant>,
    on_wake: &mut impl FnMut(Wake) -> Flow,
) -> Option<Option<Instant>> {
    if let Some(at) = deadline {
        let now = Instant::now();
        if now >= at {
            if on_wake(Wake::Tick) == Flow::Stop {
                return None;
            }
            return Some(timer(Some(now)));
        }
    }
    Some(timer(None))
}

/// Lets SIGINT and SIGTERM through to this thread (a process inherits its
/// parent's mask: the supervisor's loop holds them blocked outside its wait).
pub fn unblock_termination_signals() -> Result<(), BusError> {
    use nix::sys::signal::{SigSet, SigmaskHow, Signal};
    let mut terminating = SigSet::empty();
    terminating.add(Signal::SIGINT);
    terminating.add(Signal::SIGTERM);
    nix::sys::signal::pthread_sigmask(SigmaskHow::SIG_UNBLOCK, Some(&terminating), None)
        .map_err(|e| BusError::ipc("unblocking SIGINT and SIGTERM", e))
}

/// Sleeps until `input` has something or `timeout` passes, inside a
/// loop's cycle (a SYNC's answers, awaited up to their deadline); a
/// listener's notifications are taken. A signal only ends the wait early:
/// the loop around sees it.
pub fn wait_input(input: Input<'_>, timeout: Duration) -> Result<(), BusError> {
    use nix::errno::Errno;
    use nix::poll::{ppoll, PollFd, PollFlags};
    use nix::sys::time::TimeSpec;
    let fd = match input {
        Input::Listener(listener) => listener_fd(listener),
        Input::Socket(fd) => fd,
        Input::Doorbell(bell) => {
            bell.wait(timeout);
            return Ok(());
        }
    };
    let mut fds = [PollFd::new(fd, PollFlags::POLLIN)];
    match ppoll(&mut fds, Some(TimeSpec::from_duration(timeout)), None) {
        Ok(_) | Err(Errno::EINTR) => {}
        Err(e) => return Err(BusError::ipc("waiting on an input", e)),
    }
    if let Input::Listener(listener) = input {
        listener
            .try_wait(|_| {})
            .map_err(|e| BusError::ipc("taking an input's notification", e))?;
    }
    Ok(())
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
    input: Input<'_>,
    bus: &crate::Bus,
    mut on_input: impl FnMut() -> Flow,
) -> Result<LoopExit, BusError> {
    wait_loop(&[input], bus, |_| None, |_| on_input())
}
