//! The plant seat: which of the machine and the simulated plant drives the
//! loop's readings, the fallback when the machine is lost, and the change
//! of places asked for with `hydractl plant sim|machine`.

use hydractl_samples::code::EventKind;
use std::time::{Duration, Instant};

use anyhow::Result;
use hydractl_bus::{Bus, PendingCommand, Reader, RunScope};
use hydractl_config::{Config, SupervisorConfig};
use hydractl_samples::{code, fixed_name, service, source, PlantReading, SupervisorReply, SupervisorRequest};

use super::child::Supervised;
use super::swaps::{reply, Swaps, HANDOVER_LEAD};

/// The plant seat: which plant drives the loop's readings. With a machine,
/// the machine holds it and the simulated plant waits as the spare; when
/// the machine is lost, or on `hydractl plant sim|machine`, they change
/// places: `children[0]` is always the plant in charge.
pub(super) struct Seat {
    pub(super) source: u32,
    pub(super) spare: Option<Supervised>,
    standby_readings: Reader<PlantReading>,
    pub(super) lost_after: Duration,
}

impl Seat {
    pub(super) fn open(bus: &Bus, config: &Config) -> Result<Self> {
        Ok(Self {
            source: source::SIMULATION,
            spare: None,
            standby_readings: Reader::open(bus, service::PLANT_STANDBY, 4)?,
            lost_after: Duration::from_secs_f64(
                config.timing.control_period() * config.supervisor.machine_lost_after_periods as f64,
            ),
        })
    }

    /// Whether the simulated plant is there to take over.
    pub(super) fn can_fall_back(&self) -> bool {
        self.source == source::MACHINE && self.spare.as_ref().is_some_and(Supervised::is_running)
    }

    /// Keeps the spare: notes the machine's standby readings, restarts it
    /// as its rule says. Returns whether a dead node needs cleaning.
    pub(super) fn tick_spare(&mut self, scope: &RunScope, policy: &SupervisorConfig, now: Instant) -> Result<bool> {
        let Some(spare) = &mut self.spare else {
            return Ok(false);
        };
        while self.standby_readings.next()?.is_some() {
            spare.last_output = now;
        }
        let mut cleanup_needed = false;
        if spare.reap() {
            cleanup_needed = true;
            if !spare.after_stop(now, policy) {
                let why = spare.given_up.clone().unwrap_or_default();
                tracing::error!("the standby {} is left down: {why}", spare.name);
            }
        }
        if spare.restart_due(now) {
            spare.spawn(scope, &["--standby".to_owned()])?;
            spare.restarts += 1;
        }
        Ok(cleanup_needed)
    }

    fn change_places(&mut self, children: &mut [Supervised], now: Instant) -> u32 {
        let Some(spare) = &mut self.spare else {
            return 0;
        };
        std::mem::swap(&mut children[0], spare);
        children[0].last_output = now;
        children[0].input_resumed = now;
        children[0].last_seq = None;
        spare.last_output = now;
        children[0].pid().unwrap_or(0)
    }

    /// The machine is lost: the simulated plant takes the seat from the
    /// reading after the last one, starting from the last measured state.
    pub(super) fn fall_back(
        &mut self,
        children: &mut [Supervised],
        swaps: &mut Swaps,
        last_seq: Option<u64>,
        silent_for: Duration,
        why: &str,
        now: Instant,
    ) -> Result<()> {
        let at_seq = last_seq.map_or(0, |s| s + 1);
        let pid = self.spare.as_ref().and_then(Supervised::pid).unwrap_or(0);
        swaps.hand_over(code::STAGE_PLANT, at_seq, pid, source::SIMULATION)?;
        self.change_places(children, now);
        self.source = source::SIMULATION;
        tracing::warn!(
            "{why}: the loop now runs on the SIMULATED plant, from reading {at_seq} and the last measured state; `hydractl plant machine` goes back"
        );
        swaps.publish_plant_event(
            EventKind::Fallback,
            at_seq,
            silent_for,
            "machine",
            ("machine", "simulation"),
            pid,
        )
    }

    /// `hydractl plant sim|machine`: a live change of places, at a reading
    /// far enough ahead for both plants to see the handover.
    pub(super) fn on_request(
        &mut self,
        request: PendingCommand<SupervisorRequest, SupervisorReply>,
        children: &mut [Supervised],
        swaps: &mut Swaps,
        reading: Option<u64>,
        now: Instant,
    ) -> Result<()> {
        let to = request.request().variant;
        let from = self.source;
        let spare = match self.spare.as_ref() {
            Some(spare) if spare.is_running() => Spare::Running {
                quiet: now.saturating_duration_since(spare.last_output),
            },
            Some(_) => Spare::Down,
            None => Spare::None,
        };
        let refusal = plant_request_refusal(to, from, spare, self.lost_after, reading);
        if let Some(why) = refusal {
            return reply(request, false, from, &why);
        }
        let at_seq = reading.unwrap_or(0) + HANDOVER_LEAD;
        let pid = self.spare.as_ref().and_then(Supervised::pid).unwrap_or(0);
        swaps.hand_over(code::STAGE_PLANT, at_seq, pid, to)?;
        self.change_places(children, now);
        self.source = to;
        let message = format!("the loop runs on the {} from reading {at_seq}", plant_name(to));
        tracing::info!("as asked, {message}");
        swaps.publish_plant_event(
            EventKind::PlantSwitch,
            at_seq,
            Duration::ZERO,
            "plant",
            (plant_name(from), plant_name(to)),
            pid,
        )?;
        Ok(request.reply(SupervisorReply {
            accepted: 1,
            from_variant: from,
            message: fixed_name(&message),
            ..SupervisorReply::default()
        })?)
    }
}

/// The plant not in charge, as a request to change places sees it.
#[derive(Debug, Clone, Copy)]
enum Spare {
    /// The run has no machine.
    None,
    Down,
    /// Running, its last output `quiet` ago.
    Running {
        quiet: Duration,
    },
}

/// Why `hydractl plant sim|machine` is refused, if it is: an unknown
/// plant, the plant already in charge, a machine that sends nothing, a
/// loop with no reading yet, a spare that is down, a run with no machine.
fn plant_request_refusal(
    to: u32,
    from: u32,
    spare: Spare,
    lost_after: Duration,
    reading: Option<u64>,
) -> Option<String> {
    if to != source::MACHINE && to != source::SIMULATION {
        return Some(format!("no plant {to}: `sim` or `machine`"));
    }
    if to == from {
        return Some(format!("the loop already runs on the {}", plant_name(to)));
    }
    match spare {
        Spare::Running { quiet } if to == source::MACHINE && quiet > lost_after => Some(format!(
            "the machine sends no readings (the last came {} ms ago): the loop stays on the simulated plant",
            quiet.as_millis()
        )),
        Spare::Running { .. } if reading.is_none() => Some("the loop has no reading yet: try again".to_owned()),
        Spare::Running { .. } => None,
        Spare::Down => Some(format!("the {} is not running: try again", plant_name(to))),
        Spare::None => {
            Some("this run has no machine (its config has no [machine]): it runs on the simulated plant".to_owned())
        }
    }
}

fn plant_name(source_code: u32) -> &'static str {
    match source_code {
        source::MACHINE => "machine",
        _ => "simulation",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const LOST_AFTER: Duration = Duration::from_millis(10);

    fn running(quiet_ms: u64) -> Spare {
        Spare::Running {
            quiet: Duration::from_millis(quiet_ms),
        }
    }

    #[test]
    fn a_change_of_places_is_accepted_only_with_a_spare_that_answers_and_a_reading() {
        let (sim, machine) = (source::SIMULATION, source::MACHINE);
        assert_eq!(
            plant_request_refusal(sim, machine, running(1), LOST_AFTER, Some(7)),
            None
        );
        assert_eq!(
            plant_request_refusal(machine, sim, running(1), LOST_AFTER, Some(7)),
            None
        );
        let refused =
            |to, from, spare, reading| plant_request_refusal(to, from, spare, LOST_AFTER, reading).expect("refused");
        assert!(refused(9, sim, running(1), Some(7)).contains("no plant 9"));
        assert!(refused(sim, sim, running(1), Some(7)).contains("already runs on the simulation"));
        assert!(refused(machine, sim, running(11), Some(7)).contains("the machine sends no readings"));
        assert!(refused(sim, machine, running(1), None).contains("no reading yet"));
        assert!(refused(sim, machine, Spare::Down, Some(7)).contains("not running"));
        assert!(refused(machine, sim, Spare::None, Some(7)).contains("no [machine]"));
    }

    #[test]
    fn a_quiet_simulated_spare_may_still_take_over() {
        // The simulated plant in standby publishes nothing: only the
        // machine must be heard from before it takes the seat back.
        assert_eq!(
            plant_request_refusal(source::SIMULATION, source::MACHINE, running(500), LOST_AFTER, Some(7)),
            None
        );
    }
}
