//! The machine's CAN bus as one process sees it: [`CanPort`], over a
//! SocketCAN raw socket on the vehicle ([`SocketCanPort`]) or over the
//! virtual bus on this machine ([`VirtualCanPort`], with the `canbus`
//! process playing the wire). Both sleep in the same `ppoll` as every
//! other input ([`CanPort::input`]), see only the frames their filters
//! pass, and count error frames. Sending and receiving allocate nothing.

use std::cell::Cell;
use std::os::fd::AsFd;

use hydractl_can::Frame;
use hydractl_samples::{service, CanFrameSample};

use hydractl_bus::{clock, Bus, BusError, Inlet, Input, Outlet};

mod kernel_time;

/// Filters a port holds at most.
pub(crate) const MAX_FILTERS: usize = 16;
/// Frames the virtual port keeps for a process that is late to read.
const VIRTUAL_RX_BUFFER: usize = 256;

#[derive(Debug, thiserror::Error)]
pub enum CanPortError {
    #[error("CAN interface `{interface}` cannot be opened: {reason}")]
    Open { interface: String, reason: String },
    #[error("CAN interface `{interface}`: {what}: {source}")]
    Io {
        interface: String,
        what: &'static str,
        #[source]
        source: std::io::Error,
    },
    #[error("virtual CAN bus `{interface}`: {source}")]
    Virtual {
        interface: String,
        #[source]
        source: BusError,
    },
}

/// A frame as it arrived, stamped with the monotonic clock.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Received {
    pub frame: Frame,
    /// When the frame crossed the bus, CLOCK_MONOTONIC ns: the wire's time
    /// on the virtual bus, the kernel's receive stamp on SocketCAN; never
    /// when the process read it.
    pub time_ns: u64,
}

/// SocketCAN's acceptance filter: a frame passes when its ID and the
/// filter's agree under the mask.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Filter {
    pub id: u32,
    pub mask: u32,
}

impl Filter {
    /// Exactly this standard ID.
    pub fn exact(id: u16) -> Self {
        Self {
            id: u32::from(id),
            mask: Frame::MAX_STANDARD_ID,
        }
    }

    fn accepts(&self, frame: &Frame) -> bool {
        frame.id & self.mask == self.id & self.mask
    }
}

pub trait CanPort {
    fn interface(&self) -> &str;
    /// Hands a frame to the controller; never blocks.
    fn send(&self, frame: &Frame) -> Result<(), CanPortError>;
    /// The next frame that passed the filters, error frames included;
    /// `None` when none waits. Never blocks. (`&self`, so that a loop can
    /// sleep on [`CanPort::input`] and read in its callback.)
    fn receive(&self) -> Result<Option<Received>, CanPortError>;
    /// What to sleep on for frames.
    fn input(&self) -> Input<'_>;
    /// Error frames received so far.
    fn error_frames(&self) -> u64;
}

/// The port the `[can]` table names: its SocketCAN interface, or a station
/// on the virtual bus of that name.
pub fn open_port(
    bus: &Bus,
    profile: &hydractl_can::profile::Profile,
    filters: &[Filter],
) -> Result<Box<dyn CanPort>, CanPortError> {
    Ok(match profile.transport {
        hydractl_can::profile::Transport::Socketcan => Box::new(SocketCanPort::open(&profile.interface, filters)?),
        hydractl_can::profile::Transport::Virtual => Box::new(VirtualCanPort::open(bus, &profile.interface, filters)?),
    })
}

/// A port that listens to every frame of `profile`'s bus and must miss
/// none (a run's bus statistics): on the virtual bus a
/// [`VirtualCanPort::monitor`], on SocketCAN an unfiltered socket, whose
/// queue is the kernel's.
pub fn open_monitor(bus: &Bus, profile: &hydractl_can::profile::Profile) -> Result<Box<dyn CanPort>, CanPortError> {
    Ok(match profile.transport {
        hydractl_can::profile::Transport::Socketcan => Box::new(SocketCanPort::open(&profile.interface, &[])?),
        hydractl_can::profile::Transport::Virtual => Box::new(VirtualCanPort::monitor(bus, &profile.interface)?),
    })
}

/// Both ports' filter set, fixed size.
#[derive(Debug, Clone, Copy)]
struct Filters {
    filters: [Filter; MAX_FILTERS],
    count: usize,
}

impl Filters {
    fn new(interface: &str, filters: &[Filter]) -> Result<Self, CanPortError> {
        if filters.len() > MAX_FILTERS {
            return Err(CanPortError::Open {
                interface: interface.to_string(),
                reason: format!("{} filters, at most {MAX_FILTERS}", filters.len()),
            });
        }
        let mut all = [Filter::default(); MAX_FILTERS];
        all[..filters.len()].copy_from_slice(filters);
        Ok(Self {
            filters: all,
            count: filters.len(),
        })
    }

    fn as_slice(&self) -> &[Filter] {
        &self.filters[..self.count]
    }

    /// No filter passes everything, as an unfiltered socket does.
    fn accepts(&self, frame: &Frame) -> bool {
        frame.is_error() || self.count == 0 || self.as_slice().iter().any(|f| f.accepts(frame))
    }
}

/// A station on the virtual bus `interface`: its frames go to the wire
/// (the `canbus` process), which hands each, once it has crossed, to
/// every station. Like a SocketCAN socket, a station does not receive
/// its own frames.
pub struct VirtualCanPort {
    interface: String,
    tx: Outlet<CanFrameSample>,
    rx: Inlet<CanFrameSample>,
    station: u32,
    filters: Filters,
    sent: Cell<u64>,
    error_frames: Cell<u64>,
    /// The service keeps its last frame for late joiners; a frame from
    /// before this port opened is old news, not traffic.
    opened_ns: u64,
}

impl VirtualCanPort {
    pub fn open(bus: &Bus, interface: &str, filters: &[Filter]) -> Result<Self, CanPortError> {
        Self::open_keeping(bus, interface, filters, VIRTUAL_RX_BUFFER)
    }

    /// A station that listens to every frame and must miss none (a
    /// candump, a test's tap): it keeps [`hydractl_bus::CAN_RX_MAX_BUFFER`]
    /// frames, most of a second of the bus, for when it is late to read.
    pub fn monitor(bus: &Bus, interface: &str) -> Result<Self, CanPortError> {
        Self::open_keeping(bus, interface, &[], hydractl_bus::CAN_RX_MAX_BUFFER)
    }

    fn open_keeping(bus: &Bus, interface: &str, filters: &[Filter], kept: usize) -> Result<Self, CanPortError> {
        let virtual_error = |source| CanPortError::Virtual {
            interface: interface.to_string(),
            source,
        };
        Ok(Self {
            interface: interface.to_string(),
            rx: Inlet::open(bus, &service::can_rx(interface), kept).map_err(virtual_error)?,
            tx: Outlet::open(bus, &service::can_tx(interface)).map_err(virtual_error)?,
            station: std::process::id(),
            filters: Filters::new(interface, filters)?,
            sent: Cell::new(0),
            error_frames: Cell::new(0),
            opened_ns: clock::now_ns(),
        })
    }

    pub fn station(&self) -> u32 {
        self.station
    }

    /// Another station number than the process's: several stations in
    /// one process, as the simulated ECUs and tests are.
    pub fn with_station(mut self, station: u32) -> Self {
        self.station = station;
        self
    }
}

/// A frame as the virtual bus carries it.
pub fn frame_sample(frame: &Frame, seq: u64, time_ns: u64, station: u32) -> CanFrameSample {
    CanFrameSample {
        seq,
        time_ns,
        submitted_ns: time_ns,
        station,
        id: frame.id,
        flags: frame.flags,
        len: frame.len.min(8),
        reserved: [0; 6],
        data: frame.data,
    }
}

/// The frame a virtual bus sample carries.
pub fn sample_frame(sample: &CanFrameSample) -> Frame {
    Frame {
        id: sample.id,
        flags: sample.flags,
        len: sample.len.min(8),
        reserved: [0; 2],
        data: sample.data,
    }
}

impl CanPort for VirtualCanPort {
    fn interface(&self) -> &str {
        &self.interface
    }

    fn send(&self, frame: &Frame) -> Result<(), CanPortError> {
        self.sent.set(self.sent.get() + 1);
        self.tx
            .publish(frame_sample(frame, self.sent.get(), clock::now_ns(), self.station))
            .map_err(|source| CanPortError::Virtual {
                interface: self.interface.clone(),
                source,
            })
    }

    fn receive(&self) -> Result<Option<Received>, CanPortError> {
        loop {
            let Some(sample) = self.rx.next().map_err(|source| CanPortError::Virtual {
                interface: self.interface.clone(),
                source,
            })?
            else {
                return Ok(None);
            };
            if sample.time_ns < self.opened_ns {
                continue;
            }
            let frame = sample_frame(&sample);
            if frame.is_error() {
                self.error_frames.set(self.error_frames.get() + 1);
            } else if sample.station == self.station || !self.filters.accepts(&frame) {
                continue;
            }
            return Ok(Some(Received {
                frame,
                time_ns: sample.time_ns,
            }));
        }
    }

    fn input(&self) -> Input<'_> {
        self.rx.input()
    }

    fn error_frames(&self) -> u64 {
        self.error_frames.get()
    }
}

/// A SocketCAN raw socket on a real interface: non-blocking, filtered in
/// the kernel, error frames let through and counted, every frame stamped
/// by the kernel when it arrived (not when it was read), as the virtual
/// bus stamps it with the time it crossed the wire.
pub struct SocketCanPort {
    interface: String,
    socket: socketcan::CanSocket,
    error_frames: Cell<u64>,
    /// The receive timestamp's control message, reused.
    control: std::cell::RefCell<Vec<u8>>,
}

impl SocketCanPort {
    /// Opens `interface`; where the kernel has no SocketCAN, the interface
    /// does not exist or is down, says so and how to fix it.
    pub fn open(interface: &str, filters: &[Filter]) -> Result<Self, CanPortError> {
        use socketcan::{Socket, SocketOptions};
        let open_error = |reason: String| CanPortError::Open {
            interface: interface.to_string(),
            reason,
        };
        let filters = Filters::new(interface, filters)?;
        let socket = socketcan::CanSocket::open(interface).map_err(|e| open_error(open_failure(interface, &e)))?;
        if !interface_is_up(interface) {
            return Err(open_error(format!(
                "the interface is down; bring it up with `ip link set {interface} up type can bitrate BITRATE`"
            )));
        }
        let io = |what: &'static str| {
            move |source| CanPortError::Io {
                interface: interface.to_string(),
                what,
                source,
            }
        };
        socket
            .set_nonblocking(true)
            .map_err(io("making the socket non-blocking"))?;
        if filters.count > 0 {
            let kernel: Vec<socketcan::CanFilter> = filters
                .as_slice()
                .iter()
                .map(|f| socketcan::CanFilter::new(f.id, f.mask))
                .collect();
            socket.set_filters(&kernel).map_err(io("setting the filters"))?;
        }
        socket
            .set_error_filter_accept_all()
            .map_err(io("accepting error frames"))?;
        crate::kernel_time::enable(socket.as_fd())
            .map_err(|e| io("asking for receive timestamps")(std::io::Error::from(e)))?;
        Ok(Self {
            interface: interface.to_string(),
            socket,
            error_frames: Cell::new(0),
            control: std::cell::RefCell::new(crate::kernel_time::control_buffer()),
        })
    }
}

/// Why a CAN socket could not be opened, in words an engineer can act on.
/// The crate looks the interface up before it makes the socket, so a
/// kernel without SocketCAN shows first as a missing interface: the
/// kernel is asked for a CAN socket of its own to tell them apart.
fn open_failure(interface: &str, error: &std::io::Error) -> String {
    if let Err(errno) = kernel_has_socketcan() {
        return format!(
            "this kernel has no SocketCAN (a CAN raw socket: {}): load the `can` and `can_raw` modules, \
             or run on the virtual bus (`[can] transport = \"virtual\"`)",
            errno.desc()
        );
    }
    match error.raw_os_error() {
        Some(libc::EAFNOSUPPORT) | Some(libc::EPROTONOSUPPORT) => format!(
            "this kernel has no SocketCAN ({error}): load the `can` and `can_raw` modules, \
             or run on the virtual bus (`[can] transport = \"virtual\"`)"
        ),
        Some(libc::ENODEV) => {
            format!("there is no interface `{interface}` ({error}); `ip link show type can` lists the CAN interfaces")
        }
        Some(libc::EPERM) | Some(libc::EACCES) => format!("not permitted ({error})"),
        _ => error.to_string(),
    }
}

fn kernel_has_socketcan() -> Result<(), nix::errno::Errno> {
    use nix::sys::socket::{socket, AddressFamily, SockFlag, SockProtocol, SockType};
    socket(
        AddressFamily::Can,
        SockType::Raw,
        SockFlag::SOCK_CLOEXEC,
        SockProtocol::CanRaw,
    )
    .map(drop)
}

fn interface_is_up(interface: &str) -> bool {
    // IFF_UP is bit 0 of the interface's flags.
    std::fs::read_to_string(format!("/sys/class/net/{interface}/flags"))
        .ok()
        .and_then(|flags| u32::from_str_radix(flags.trim().trim_start_matches("0x"), 16).ok())
        .is_some_and(|flags| flags & 1 != 0)
}

const CAN_EFF_FLAG: u32 = 0x8000_0000;
const CAN_RTR_FLAG: u32 = 0x4000_0000;
const CAN_ERR_FLAG: u32 = 0x2000_0000;

impl CanPort for SocketCanPort {
    fn interface(&self) -> &str {
        &self.interface
    }

    fn send(&self, frame: &Frame) -> Result<(), CanPortError> {
        use socketcan::Socket;
        if frame.is_error() {
            return Err(CanPortError::Io {
                interface: self.interface.clone(),
                what: "sending a frame",
                source: std::io::Error::new(
                    std::io::ErrorKind::InvalidInput,
                    "error frames are made by the controllers, not sent",
                ),
            });
        }
        let mut raw = socketcan::frame::can_frame_default();
        raw.can_id = frame.id
            | if frame.is_extended() { CAN_EFF_FLAG } else { 0 }
            | if frame.is_remote() { CAN_RTR_FLAG } else { 0 };
        raw.can_dlc = frame.len.min(8);
        raw.data = frame.data;
        self.socket
            .write_frame(&socketcan::CanFrame::from(raw))
            .map_err(|source| CanPortError::Io {
                interface: self.interface.clone(),
                what: "sending a frame",
                source,
            })
    }

    fn receive(&self) -> Result<Option<Received>, CanPortError> {
        // `struct can_frame`: the ID with its flags, the length, three
        // bytes of padding and reserved fields, eight of data.
        let mut raw = [0u8; 16];
        let received = crate::kernel_time::receive(self.socket.as_fd(), &mut raw, &mut self.control.borrow_mut());
        let (len, stamp) = match received {
            Ok(Some(got)) => got,
            Ok(None) => return Ok(None),
            Err(errno) => {
                return Err(CanPortError::Io {
                    interface: self.interface.clone(),
                    what: "receiving",
                    source: errno.into(),
                })
            }
        };
        if len < raw.len() {
            return Err(CanPortError::Io {
                interface: self.interface.clone(),
                what: "receiving",
                source: std::io::Error::new(
                    std::io::ErrorKind::InvalidData,
                    format!("{len} bytes, a CAN frame is 16 (a CAN FD frame on a classic socket?)"),
                ),
            });
        }
        let time_ns = stamp.unwrap_or_else(clock::now_ns);
        let can_id = u32::from_ne_bytes([raw[0], raw[1], raw[2], raw[3]]);
        let mut flags = 0;
        if can_id & CAN_EFF_FLAG != 0 {
            flags |= Frame::EXTENDED;
        }
        if can_id & CAN_RTR_FLAG != 0 {
            flags |= Frame::REMOTE;
        }
        if can_id & CAN_ERR_FLAG != 0 {
            flags |= Frame::ERROR;
            self.error_frames.set(self.error_frames.get() + 1);
        }
        let mut data = [0u8; 8];
        data.copy_from_slice(&raw[8..16]);
        let frame = Frame {
            id: can_id & Frame::MAX_EXTENDED_ID,
            flags,
            len: raw[4].min(8),
            reserved: [0; 2],
            data,
        };
        Ok(Some(Received { frame, time_ns }))
    }

    fn input(&self) -> Input<'_> {
        Input::Socket(self.socket.as_fd())
    }

    fn error_frames(&self) -> u64 {
        self.error_frames.get()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_real_interface_that_cannot_be_opened_is_named_with_the_reason() {
        // This machine's kernel has no SocketCAN; where one has, `nocan9`
        // does not exist. Either way: an error naming the interface.
        let error = SocketCanPort::open("nocan9", &[Filter::exact(0x181)])
            .err()
            .expect("no such interface here");
        let text = error.to_string();
        assert!(text.starts_with("CAN interface `nocan9` cannot be opened: "), "{text}");
        assert!(
            text.contains("no SocketCAN") || text.contains("there is no interface `nocan9`"),
            "{text}"
        );
    }

    #[test]
    fn filters_pass_what_socketcan_would() {
        let filters = Filters::new("x", &[Filter::exact(0x181), Filter { id: 0x700, mask: 0x780 }]).expect("filters");
        let frame = |id| Frame::new(id, &[]).expect("frame");
        assert!(filters.accepts(&frame(0x181)));
        assert!(!filters.accepts(&frame(0x182)));
        assert!(filters.accepts(&frame(0x720)), "every heartbeat");
        assert!(filters.accepts(&Frame::error(4, [0; 8])), "error frames always");
        assert!(Filters::new("x", &[]).expect("none").accepts(&frame(0x555)));
        assert!(Filters::new("x", &[Filter::default(); MAX_FILTERS + 1]).is_err());
    }

    #[test]
    fn frames_cross_the_virtual_bus_sample_unchanged() {
        let frame = Frame::new(0x210, &[0, 0, 0x00, 0x20]).expect("frame");
        assert_eq!(sample_frame(&frame_sample(&frame, 1, 2, 3)), frame);
    }
}
