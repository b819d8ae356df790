//! When a datagram reached the socket, by the kernel's own receive
//! timestamp (`SO_TIMESTAMPNS`), on the monotonic clock: not when the
//! process got round to reading it. A CAN master that compares a PDO with
//! its SYNC by the time it read the PDO takes one that arrived before the
//! SYNC but was read after it for the SYNC's answer.

use std::io::IoSliceMut;
use std::os::fd::{AsRawFd, BorrowedFd};

use nix::sys::socket::{recvmsg, setsockopt, sockopt, ControlMessageOwned, MsgFlags};
use nix::sys::time::TimeSpec;
use nix::time::{clock_gettime, ClockId};

/// Asks the kernel to stamp every datagram `fd` receives.
pub fn enable(fd: BorrowedFd<'_>) -> nix::Result<()> {
    setsockopt(&fd, sockopt::ReceiveTimestampns, &true)
}

/// Room for the timestamp's control message, made once per socket. (The
/// kernel turns stamping on in deferred work: the first datagrams after
/// [`enable`] may be stamped when read.)
pub fn control_buffer() -> Vec<u8> {
    nix::cmsg_space!(TimeSpec)
}

/// One datagram into `buf`, without blocking: its length and when the
/// kernel received it (CLOCK_MONOTONIC ns; `None` when the kernel gave no
/// stamp), or `None` when nothing waits. `control` is
/// [`control_buffer`]'s, reused: nothing is allocated per datagram.
pub fn receive(fd: BorrowedFd<'_>, buf: &mut [u8], control: &mut [u8]) -> nix::Result<Option<(usize, Option<u64>)>> {
    let mut iov = [IoSliceMut::new(buf)];
    let message = match recvmsg::<()>(fd.as_raw_fd(), &mut iov, Some(control), MsgFlags::MSG_DONTWAIT) {
        Ok(message) => message,
        Err(nix::errno::Errno::EAGAIN) => return Ok(None),
        Err(e) => return Err(e),
    };
    let mut stamp = None;
    for cmsg in message.cmsgs()? {
        if let ControlMessageOwned::ScmTimestampns(t) = cmsg {
            stamp = Some(realtime_to_monotonic(t));
        }
    }
    Ok(Some((message.bytes, stamp)))
}

/// The kernel stamps with CLOCK_REALTIME; the stack's time base is
/// CLOCK_MONOTONIC. The two clocks' offset now converts it (a step of the
/// wall clock between the stamp and now would shift it: rare, and bounded
/// by the step).
fn realtime_to_monotonic(stamp: TimeSpec) -> u64 {
    let ns = |t: TimeSpec| t.tv_sec() as i128 * 1_000_000_000 + t.tv_nsec() as i128;
    let (Ok(real), Ok(mono)) = (
        clock_gettime(ClockId::CLOCK_REALTIME),
        clock_gettime(ClockId::CLOCK_MONOTONIC),
    ) else {
        return hydractl_bus::clock::now_ns();
    };
    (ns(stamp) - (ns(real) - ns(mono))).max(0) as u64
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::net::UdpSocket;
    use std::os::fd::AsFd;
    use std::time::Duration;

    #[test]
    fn a_datagram_is_stamped_when_it_arrived_not_when_it_was_read() {
        // UDP on the loopback: the same kernel stamping as a CAN raw
        // socket's, which this machine's kernel does not have.
        let receiver = UdpSocket::bind("127.0.0.1:0").expect("bind");
        let sender = UdpSocket::bind("127.0.0.1:0").expect("bind");
        enable(receiver.as_fd()).expect("timestamps");
        // The kernel turns its stamping on in deferred work: until then a
        // datagram is stamped when read. A socket open for a whole run is
        // past that long before its first frame.
        std::thread::sleep(Duration::from_millis(100));
        let mut control = control_buffer();
        let mut buf = [0u8; 16];
        assert_eq!(
            receive(receiver.as_fd(), &mut buf, &mut control),
            Ok(None),
            "nothing waits"
        );
        let sent_ns = hydractl_bus::clock::now_ns();
        sender
            .send_to(&[7; 16], receiver.local_addr().expect("address"))
            .expect("send");
        std::thread::sleep(Duration::from_millis(30));
        let read_ns = hydractl_bus::clock::now_ns();
        let (len, stamp) = receive(receiver.as_fd(), &mut buf, &mut control)
            .expect("receive")
            .expect("a datagram");
        assert_eq!((len, buf), (16, [7; 16]));
        let stamp = stamp.expect("stamped by the kernel");
        assert!(
            stamp >= sent_ns.saturating_sub(1_000_000) && stamp + 20_000_000 < read_ns,
            "sent {sent_ns}, stamped {stamp}, read {read_ns}"
        );
    }
}
