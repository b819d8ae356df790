use std::fmt::Debug;
use std::time::Duration;

use iceoryx2::port::listener::{Listener, ListenerWaitError};
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;

use crate::{Bus, BusError, Doorbell, Input};

/// The same QoS for every opener, so that creating and opening agree.
/// Safe overflow (iceoryx2's default) means a slow reader loses its oldest
/// samples and never blocks a publisher.
const MAX_BUFFER: usize = 256;
/// A CAN bus's delivered traffic may be kept longer for a reader that
/// wants every frame (the recorder): the stack's bus carries about six
/// frames per millisecond, so the 256 of other services would be only 43
/// ms of it.
pub const CAN_RX_MAX_BUFFER: usize = 4096;
const MAX_SUBSCRIBERS: usize = 16;
// The handover acknowledgements have one publisher per controller and plant.
const MAX_PUBLISHERS: usize = 8;
const MAX_NODES: usize = 32;

type DataService<T> = iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, T, ()>;
type EventService = iceoryx2::service::port_factory::event::PortFactory<ipc::Service>;

/// The publish-subscribe service `name` with the one QoS every opener uses.
fn data_service<T: ZeroCopySend + Debug + Copy + 'static>(
    bus: &Bus,
    service_name: &ServiceName,
) -> iceoryx2::service::builder::publish_subscribe::Builder<T, (), ipc::Service> {
    bus.node()
        .service_builder(service_name)
        .publish_subscribe::<T>()
        .subscriber_max_buffer_size(max_buffer(service_name.as_str()))
        .max_subscribers(MAX_SUBSCRIBERS)
        .max_publishers(MAX_PUBLISHERS)
        .max_nodes(MAX_NODES)
        .history_size(1)
}

/// The most samples a reader of the service `name` may keep.
fn max_buffer(name: &str) -> usize {
    if hydractl_samples::service::can_rx_interface(name).is_some() {
        CAN_RX_MAX_BUFFER
    } else {
        MAX_BUFFER
    }
}

fn open_data<T: ZeroCopySend + Debug + Copy + 'static>(bus: &Bus, name: &str) -> Result<DataService<T>, BusError> {
    let service_name = ServiceName::new(name).map_err(|e| BusError::ipc(format!("service name {name}"), e))?;
    data_service::<T>(bus, &service_name)
        .open_or_create()
        .map_err(|e| BusError::ipc(format!("opening {name}"), e))
}

fn open_event(bus: &Bus, name: &str) -> Result<EventService, BusError> {
    let service_name = ServiceName::new(name).map_err(|e| BusError::ipc(format!("service name {name}"), e))?;
    bus.node()
        .service_builder(&service_name)
        .event()
        .max_nodes(MAX_NODES + 4)
        // Only event 0 is sent. Each wake-up drains every event id's counter
        // (one atomic swap each): iceoryx2's default of 256 ids cost about
        // 2 µs per hop.
        .event_id_max_value(0)
        .open_or_create()
        .map_err(|e| BusError::ipc(format!("opening event {name}"), e))
}

/// How a sample wakes whoever waits for it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Wakeup {
    /// An iceoryx2 event: a datagram on a unix socket, which `ppoll` can
    /// wait on beside other inputs.
    Event,
    /// The service's [`Doorbell`], a futex: the fastest hop, for a stage
    /// that waits on that one input.
    Doorbell,
}

impl Wakeup {
    /// The loop's services ring doorbells; every other service notifies
    /// an event ([`hydractl_samples::service::rings_doorbell`]).
    pub fn of(service: &str) -> Self {
        if hydractl_samples::service::rings_doorbell(service) {
            Self::Doorbell
        } else {
            Self::Event
        }
    }
}

/// Counts the publishers of a service without adding a port and without
/// creating the service: for a process that, at start-up, waits for the
/// ones it depends on. Opening a service that is not there would create
/// it, and dropping that handle remove it again, under the feet of the
/// process that is creating it.
pub struct PublisherWatch<T: ZeroCopySend + Debug + Copy + 'static> {
    name: String,
    service: Option<DataService<T>>,
}

impl<T: ZeroCopySend + Debug + Copy + 'static> PublisherWatch<T> {
    pub fn new(name: &str) -> Self {
        Self {
            name: name.to_owned(),
            service: None,
        }
    }

    /// The publishers now; 0 while the service does not exist or cannot be
    /// opened yet (its creator may be half-way).
    pub fn publishers(&mut self, bus: &Bus) -> usize {
        use iceoryx2::service::port_factory::PortFactory;
        if self.service.is_none() {
            self.service = ServiceName::new(&self.name)
                .ok()
                .and_then(|service_name| data_service::<T>(bus, &service_name).open().ok());
        }
        self.service
            .as_ref()
            .map_or(0, |service| service.dynamic_config().number_of_publishers())
    }

    /// The process id of each publisher on the service (an iceoryx2 node id
    /// carries its creator's): who may be a stranger to the run.
    pub fn publisher_pids(&mut self, bus: &Bus) -> Vec<u32> {
        use iceoryx2::service::port_factory::PortFactory;
        self.publishers(bus);
        let mut pids = Vec::new();
        if let Some(service) = &self.service {
            service.dynamic_config().list_publishers(|details| {
                if let Ok(pid) = details.node_id.pid::<ipc::Service>() {
                    pids.push(pid.value() as u32);
                }
                CallbackProgression::Continue
            });
        }
        pids
    }
}

/// What an [`Outlet`] wakes its readers with.
// One per port, made at start: the event's size is no cost.
#[allow(clippy::large_enum_variant)]
enum Waker {
    Event(Notifier<ipc::Service>),
    Doorbell(Doorbell),
}

/// Publishes samples of one service and wakes its readers.
pub struct Outlet<T: ZeroCopySend + Debug + Copy + 'static> {
    name: String,
    publisher: Publisher<ipc::Service, T, ()>,
    waker: Waker,
}

impl<T: ZeroCopySend + Debug + Copy + 'static> Outlet<T> {
    /// Opens the service `name`, waking its readers as [`Wakeup::of`] says.
    pub fn open(bus: &Bus, name: &str) -> Result<Self, BusError> {
        Self::open_waking(bus, name, Wakeup::of(name))
    }

    pub fn open_waking(bus: &Bus, name: &str, wakeup: Wakeup) -> Result<Self, BusError> {
        let publisher = open_data::<T>(bus, name)?
            .publisher_builder()
            .create()
            .map_err(|e| BusError::ipc(format!("publisher on {name}"), e))?;
        let waker = match wakeup {
            Wakeup::Event => Waker::Event(
                open_event(bus, name)?
                    .notifier_builder()
                    .create()
                    .map_err(|e| BusError::ipc(format!("notifier on {name}"), e))?,
            ),
            Wakeup::Doorbell => Waker::Doorbell(Doorbell::open(bus.scope(), name)?),
        };
        Ok(Self {
            name: name.to_owned(),
            publisher,
            waker,
        })
    }

    pub fn name(&self) -> &str {
        &self.name
    }

    /// Sends one sample zero-copy and notifies. Allocation-free.
    pub fn publish(&self, value: T) -> Result<(), BusError> {
        let sample = self
            .publisher
            .loan_uninit()
            .map_err(|e| BusError::ipc(format!("loan on {}", self.name), e))?;
        sample
            .write_payload(value)
            .send()
            .map_err(|e| BusError::ipc(format!("send on {}", self.name), e))?;
        match &self.waker {
            Waker::Event(notifier) => {
                notifier
                    .notify()
                    .map_err(|e| BusError::ipc(format!("notify on {}", self.name), e))?;
            }
            Waker::Doorbell(bell) => bell.ring(),
        }
        Ok(())
    }
}

/// Reads samples of one service by polling: for a process that looks on
/// its own tick (supervisor, monitor) or reads a side input when another
/// input wakes it. It opens no listener, so publishers do not notify it.
pub struct Reader<T: ZeroCopySend + Debug + Copy + 'static> {
    name: String,
    subscriber: Subscriber<ipc::Service, T, ()>,
}

impl<T: ZeroCopySend + Debug + Copy + 'static> Reader<T> {
    /// `buffer` samples are kept for this reader: 1–4 for one that only
    /// wants the newest, more for a monitor that wants every one, at most
    /// 256 ([`CAN_RX_MAX_BUFFER`] on a CAN bus's delivered frames).
    pub fn open(bus: &Bus, name: &str, buffer: usize) -> Result<Self, BusError> {
        let subscriber = open_data::<T>(bus, name)?
            .subscriber_builder()
            .buffer_size(buffer.clamp(1, max_buffer(name)))
            .create()
            .map_err(|e| BusError::ipc(format!("subscriber on {name}"), e))?;
        Ok(Self {
            name: name.to_owned(),
            subscriber,
        })
    }

    pub fn name(&self) -> &str {
        &self.name
    }

    /// The next waiting sample, oldest first.
    pub fn next(&self) -> Result<Option<T>, BusError> {
        self.subscriber
            .receive()
            .map(|sample| sample.map(|s| *s.payload()))
            .map_err(|e| BusError::ipc(format!("receive on {}", self.name), e))
    }

    /// The waiting sample with the greatest `key`, dropping the others: with
    /// two publishers (a plant handing over to another), samples arrive
    /// publisher by publisher, not in the order they were published.
    pub fn newest_by<K: Ord>(&self, key: impl Fn(&T) -> K) -> Result<Option<T>, BusError> {
        let mut newest: Option<T> = None;
        while let Some(sample) = self.next()? {
            if newest.as_ref().is_none_or(|n| key(&sample) >= key(n)) {
                newest = Some(sample);
            }
        }
        Ok(newest)
    }

    /// The newest waiting sample, dropping older ones.
    pub fn latest(&self) -> Result<Option<T>, BusError> {
        let mut newest = None;
        while let Some(sample) = self.next()? {
            newest = Some(sample);
        }
        Ok(newest)
    }

    /// The newest sample, waiting for one up to `within` (polling every
    /// 10 ms): for a tool that asks a running stack once, never for a loop.
    pub fn latest_within(&self, within: Duration) -> Result<Option<T>, BusError> {
        let deadline = std::time::Instant::now() + within;
        loop {
            if let Some(sample) = self.latest()? {
                return Ok(Some(sample));
            }
            if std::time::Instant::now() > deadline {
                return Ok(None);
            }
            std::thread::sleep(Duration::from_millis(10));
        }
    }
}

/// What an [`Inlet`] sleeps on.
// One per port, made at start: the listener's size is no cost.
#[allow(clippy::large_enum_variant)]
enum Wait {
    Event(Listener<ipc::Service>),
    Doorbell(Doorbell),
}

/// Receives samples of one service and wakes its process: a [`Reader`] with
/// what to sleep on, for [`crate::run_loop`], [`crate::run_until`] or
/// [`crate::run_single`].
pub struct Inlet<T: ZeroCopySend + Debug + Copy + 'static> {
    reader: Reader<T>,
    wait: Wait,
}

impl<T: ZeroCopySend + Debug + Copy + 'static> Inlet<T> {
    /// Opens the service `name`, woken as [`Wakeup::of`] says.
    pub fn open(bus: &Bus, name: &str, buffer: usize) -> Result<Self, BusError> {
        Self::open_waking(bus, name, buffer, Wakeup::of(name))
    }

    pub fn open_waking(bus: &Bus, name: &str, buffer: usize, wakeup: Wakeup) -> Result<Self, BusError> {
        let reader = Reader::open(bus, name, buffer)?;
        let wait = match wakeup {
            Wakeup::Event => Wait::Event(
                open_event(bus, name)?
                    .listener_builder()
                    .create()
                    .map_err(|e| BusError::ipc(format!("listener on {name}"), e))?,
            ),
            Wakeup::Doorbell => Wait::Doorbell(Doorbell::open(bus.scope(), name)?),
        };
        Ok(Self { reader, wait })
    }

    pub fn name(&self) -> &str {
        &self.reader.name
    }

    /// What to sleep on for this inlet's samples.
    pub fn input(&self) -> Input<'_> {
        match &self.wait {
            Wait::Event(listener) => Input::Listener(listener),
            Wait::Doorbell(bell) => Input::Doorbell(bell),
        }
    }

    pub fn next(&self) -> Result<Option<T>, BusError> {
        self.reader.next()
    }

    pub fn latest(&self) -> Result<Option<T>, BusError> {
        self.reader.latest()
    }

    pub fn newest_by<K: Ord>(&self, key: impl Fn(&T) -> K) -> Result<Option<T>, BusError> {
        self.reader.newest_by(key)
    }

    /// Blocks until a sample arrives or `timeout` passes; the newest sample.
    pub fn wait_latest(&self, timeout: Duration) -> Result<Option<T>, BusError> {
        if let Some(sample) = self.latest()? {
            return Ok(Some(sample));
        }
        // A zero timeout becomes a socket receive timeout of zero, which the
        // kernel reads as "block forever".
        if timeout < Duration::from_micros(1) {
            return Ok(None);
        }
        match &self.wait {
            // The listener's own timed wait, not `ppoll` as in `run_loop`:
            // for the plant, which waits here right after publishing a
            // reading, it measured faster to the sensor's wake-up, although
            // it makes more system calls.
            Wait::Event(listener) => match listener.timed_wait(|_| {}, timeout) {
                // Any signal interrupts the sleep; it is the caller's loop
                // that decides whether a signal ends the run.
                Ok(_) | Err(ListenerWaitError::InterruptSignal) => {}
                Err(e) => return Err(BusError::ipc(format!("wait on {}", self.name()), e)),
            },
            // A timeout, a ring or a signal: each ends the sleep the same.
            Wait::Doorbell(bell) => {
                bell.wait(timeout);
            }
        }
        self.latest()
    }
}
