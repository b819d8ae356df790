//! An iceoryx2 service type like `ipc::Service` but for its events: a
//! semaphore in shared memory (a futex) instead of a datagram on a unix
//! socket. A notification is one `futex` wake, a wait one `futex` wait; no
//! socket, no `ppoll`. The price: a listener cannot be waited on together
//! with other inputs, its timed wait is a spin-and-sleep loop on a
//! monotonic clock, and iceoryx2's signal handler restarts a blocking
//! wait. The latency benchmark's third transport, to measure what the
//! chain's single-input hops would gain; the live stack's waits need a
//! timeout and a `ppoll` beside other inputs, which it cannot give.

use core::fmt::Debug;

use iceoryx2::service::internal::ServiceInternal;
use iceoryx2_bb_elementary_traits::testing::abandonable::Abandonable;
use iceoryx2_bb_elementary_traits::zero_copy_send::ZeroCopySend;
use iceoryx2_cal::shm_allocator::bump_allocator::BumpAllocator;
use iceoryx2_cal::shm_allocator::pool_allocator::PoolAllocator;
use iceoryx2_cal::{
    arc_sync_policy, bag, dynamic_storage, event, hash, monitoring, reactor, resizable_shared_memory, serialize,
    shared_memory, static_storage, zero_copy_connection,
};

/// `ipc::Service` with semaphore events (iceoryx2-cal's
/// `SemaphoreShmCountingBitSet`); every other part is iceoryx2's
/// recommended inter-process choice, as in `ipc::Service`.
#[derive(Debug, Clone)]
pub struct SemaphoreIpc {}

impl iceoryx2::service::Service for SemaphoreIpc {
    type StaticStorage = static_storage::recommended::Ipc;
    type ConfigSerializer = serialize::recommended::Recommended;
    type PersistentDynamicStorage<T: Debug + Send + Sync + ZeroCopySend + 'static> =
        dynamic_storage::recommended::PersistentIpc<T>;
    type Bag = bag::recommended::Recommended;
    type DynamicStorage<T: Debug + Send + Sync + ZeroCopySend + 'static> = dynamic_storage::recommended::Ipc<T>;
    type ServiceNameHasher = hash::recommended::Recommended;
    type SharedMemory = shared_memory::recommended::Ipc<PoolAllocator>;
    type ResizableSharedMemory = resizable_shared_memory::recommended::Ipc<PoolAllocator>;
    type Connection = zero_copy_connection::recommended::Ipc;
    type Event = event::SemaphoreShmCountingBitSet;
    type Monitoring = monitoring::recommended::Ipc;
    type Reactor = reactor::recommended::Ipc;
    type ArcThreadSafetyPolicy<T: Send + Debug + Abandonable> = arc_sync_policy::single_threaded::SingleThreaded<T>;
    type BlackboardMgmt<KeyType: Send + Sync + Debug + ZeroCopySend + 'static> =
        dynamic_storage::recommended::Ipc<KeyType>;
    type BlackboardPayload = shared_memory::recommended::Ipc<BumpAllocator>;
    type UniqueId = iceoryx2::unique_id_generator::unique_system_id::UniqueSystemId;
}

impl ServiceInternal<SemaphoreIpc> for SemaphoreIpc {}

use iceoryx2::node::Node;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;

use hydractl_bus::{BusError, RunScope};

/// An iceoryx2 error as the bus reports its own.
fn ipc(what: impl Into<String>, detail: impl Debug) -> BusError {
    BusError::Ipc {
        what: what.into(),
        detail: format!("{detail:?}"),
    }
}

/// A node of `scope` whose services have semaphore events. Its files carry
/// the scope's prefix; `RunScope::remove_all_files` takes them.
pub fn open_node(scope: &RunScope) -> Result<Node<SemaphoreIpc>, BusError> {
    NodeBuilder::new()
        .config(&scope.config()?)
        .create::<SemaphoreIpc>()
        .map_err(|e| ipc("creating a node with semaphore events", e))
}

/// The next stage and up to [`MAX_OBSERVERS`] readers that only look.
const MAX_SUBSCRIBERS: usize = MAX_OBSERVERS + 1;
pub const MAX_OBSERVERS: usize = 8;

fn open_data<T: ZeroCopySend + Debug + Copy + 'static>(
    node: &Node<SemaphoreIpc>,
    name: &str,
) -> Result<iceoryx2::service::port_factory::publish_subscribe::PortFactory<SemaphoreIpc, T, ()>, BusError> {
    let service_name = ServiceName::new(name).map_err(|e| ipc(format!("service name {name}"), e))?;
    node.service_builder(&service_name)
        .publish_subscribe::<T>()
        .history_size(1)
        .subscriber_max_buffer_size(4)
        .max_subscribers(MAX_SUBSCRIBERS)
        .open_or_create()
        .map_err(|e| ipc(format!("opening {name}"), e))
}

fn open_event(
    node: &Node<SemaphoreIpc>,
    name: &str,
) -> Result<iceoryx2::service::port_factory::event::PortFactory<SemaphoreIpc>, BusError> {
    let service_name = ServiceName::new(name).map_err(|e| ipc(format!("service name {name}"), e))?;
    node.service_builder(&service_name)
        .event()
        .event_id_max_value(0)
        .open_or_create()
        .map_err(|e| ipc(format!("opening event {name}"), e))
}

/// Publishes and notifies, as [`hydractl_bus::Outlet`].
pub struct SemaphoreOutlet<T: ZeroCopySend + Debug + Copy + 'static> {
    publisher: Publisher<SemaphoreIpc, T, ()>,
    notifier: Notifier<SemaphoreIpc>,
}

impl<T: ZeroCopySend + Debug + Copy + 'static> SemaphoreOutlet<T> {
    pub fn open(node: &Node<SemaphoreIpc>, name: &str) -> Result<Self, BusError> {
        Ok(Self {
            publisher: open_data::<T>(node, name)?
                .publisher_builder()
                .create()
                .map_err(|e| ipc(format!("publisher on {name}"), e))?,
            notifier: open_event(node, name)?
                .notifier_builder()
                .create()
                .map_err(|e| ipc(format!("notifier on {name}"), e))?,
        })
    }

    pub fn publish(&self, value: T) -> Result<(), BusError> {
        self.publisher
            .send_copy(value)
            .map_err(|e| ipc("send with semaphore events", e))?;
        self.notifier
            .notify()
            .map_err(|e| ipc("notify with semaphore events", e))?;
        Ok(())
    }
}

/// Wakes the listeners of a service without publishing: for a watchdog
/// that must end a blocking wait.
pub struct SemaphoreWaker(Notifier<SemaphoreIpc>);

impl SemaphoreWaker {
    pub fn open(node: &Node<SemaphoreIpc>, name: &str) -> Result<Self, BusError> {
        let notifier = open_event(node, name)?
            .notifier_builder()
            .create()
            .map_err(|e| ipc(format!("waker on {name}"), e))?;
        Ok(Self(notifier))
    }

    pub fn wake(&self) -> Result<(), BusError> {
        self.0
            .notify()
            .map(|_| ())
            .map_err(|e| ipc("waking with semaphore events", e))
    }
}

/// Receives samples by polling, with no listener: publishers do not wake
/// it, as [`hydractl_bus::Reader`].
pub struct SemaphoreReader<T: ZeroCopySend + Debug + Copy + 'static> {
    subscriber: Subscriber<SemaphoreIpc, T, ()>,
}

impl<T: ZeroCopySend + Debug + Copy + 'static> SemaphoreReader<T> {
    pub fn open(node: &Node<SemaphoreIpc>, name: &str) -> Result<Self, BusError> {
        Ok(Self {
            subscriber: open_data::<T>(node, name)?
                .subscriber_builder()
                .buffer_size(4)
                .create()
                .map_err(|e| ipc(format!("subscriber on {name}"), e))?,
        })
    }

    pub fn next(&self) -> Result<Option<T>, BusError> {
        self.subscriber
            .receive()
            .map(|sample| sample.map(|s| *s.payload()))
            .map_err(|e| ipc("receive with semaphore events", e))
    }
}

/// Receives samples and sleeps on the semaphore until one is notified.
pub struct SemaphoreInlet<T: ZeroCopySend + Debug + Copy + 'static> {
    reader: SemaphoreReader<T>,
    listener: Listener<SemaphoreIpc>,
}

impl<T: ZeroCopySend + Debug + Copy + 'static> SemaphoreInlet<T> {
    pub fn open(node: &Node<SemaphoreIpc>, name: &str) -> Result<Self, BusError> {
        Ok(Self {
            reader: SemaphoreReader::open(node, name)?,
            listener: open_event(node, name)?
                .listener_builder()
                .create()
                .map_err(|e| ipc(format!("listener on {name}"), e))?,
        })
    }

    /// Sleeps until notified (a signal ends the sleep too, as a wake-up).
    pub fn wait(&self) -> Result<(), BusError> {
        match self.listener.blocking_wait(|_| {}) {
            Ok(_) | Err(iceoryx2::port::listener::ListenerWaitError::InterruptSignal) => Ok(()),
            Err(e) => Err(ipc("waiting with semaphore events", e)),
        }
    }

    pub fn next(&self) -> Result<Option<T>, BusError> {
        self.reader.next()
    }
}
