//! Publishers on the run's services that are not the run's own processes:
//! any process of the run's user can open them (iceoryx2 has no access
//! control beyond file modes). The valve's guard bounds what a stranger's
//! commands can do (SAFETY.md, H10); the supervisor finds the stranger and
//! says so, once per process and service.

use std::time::{Duration, Instant};

use hydractl_bus::{Bus, PublisherWatch};
use hydractl_samples::{
    service, FrictionSample, Handover, HandoverAck, PlantReading, PositionSample, SensorSample, TorqueSample,
    ValveSample,
};

/// How often the services' publishers are looked at.
const LOOK_EVERY: Duration = Duration::from_millis(100);

pub(super) struct Strangers {
    plant: PublisherWatch<PlantReading>,
    sensor: PublisherWatch<SensorSample>,
    friction: PublisherWatch<FrictionSample>,
    position: PublisherWatch<PositionSample>,
    torque: PublisherWatch<TorqueSample>,
    valve: PublisherWatch<ValveSample>,
    handover: PublisherWatch<Handover>,
    ack: PublisherWatch<HandoverAck>,
    last_look: Option<Instant>,
    /// (pid, service) already reported.
    reported: Vec<(u32, &'static str)>,
}

impl Strangers {
    pub(super) fn new() -> Self {
        Self {
            plant: PublisherWatch::new(service::PLANT_READING),
            sensor: PublisherWatch::new(service::SENSOR),
            friction: PublisherWatch::new(service::FRICTION),
            position: PublisherWatch::new(service::POSITION),
            torque: PublisherWatch::new(service::TORQUE),
            valve: PublisherWatch::new(service::VALVE),
            handover: PublisherWatch::new(service::HANDOVER),
            ack: PublisherWatch::new(service::HANDOVER_ACK),
            last_look: None,
            reported: Vec::new(),
        }
    }

    /// Every `LOOK_EVERY`: the publishers on the loop's and the handovers'
    /// services whose process is none of `ours`, not reported before.
    pub(super) fn look(&mut self, bus: &Bus, now: Instant, ours: &[u32]) -> Vec<(u32, &'static str)> {
        if self
            .last_look
            .is_some_and(|at| now.saturating_duration_since(at) < LOOK_EVERY)
        {
            return Vec::new();
        }
        self.last_look = Some(now);
        let found = [
            (service::PLANT_READING, self.plant.publisher_pids(bus)),
            (service::SENSOR, self.sensor.publisher_pids(bus)),
            (service::FRICTION, self.friction.publisher_pids(bus)),
            (service::POSITION, self.position.publisher_pids(bus)),
            (service::TORQUE, self.torque.publisher_pids(bus)),
            (service::VALVE, self.valve.publisher_pids(bus)),
            (service::HANDOVER, self.handover.publisher_pids(bus)),
            (service::HANDOVER_ACK, self.ack.publisher_pids(bus)),
        ];
        let mut new = Vec::new();
        for (name, pids) in found {
            for pid in pids {
                if !ours.contains(&pid) && !self.reported.contains(&(pid, name)) {
                    self.reported.push((pid, name));
                    new.push((pid, name));
                }
            }
        }
        new
    }
}
