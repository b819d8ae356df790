//! Hot swaps of the position or torque controller, and the supervisor's
//! handovers and events.

use hydractl_samples::code::EventKind;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::Result;
use hydractl_bus::{clock, Bus, Outlet, PendingCommand, Reader, RunScope};
use hydractl_samples::{
    code, fixed_name, service, Handover, HandoverAck, PositionSample, SupervisorEvent, SupervisorReply,
    SupervisorRequest, TorqueSample, ValveSample,
};

use super::child::Supervised;
use super::faults::Fault;
use super::tracking::{worse_enough, TrackingLog};
use super::valve_log::{SwitchQuality, ValveLog};

/// Hot swaps of the position or torque controller, asked for over
/// `hydractl/supervisor/command`: the new variant starts as a standby
/// process that tracks the running one; once it answers, a handover names
/// the reading from which it is in charge; the valve's samples around that
/// reading judge the switch; then the old process is stopped.
pub(super) struct Swaps {
    handovers: Outlet<Handover>,
    events: Outlet<SupervisorEvent>,
    valve: Reader<ValveSample>,
    standby_position: Reader<PositionSample>,
    standby_torque: Reader<TorqueSample>,
    acks: Reader<HandoverAck>,
    position: Reader<PositionSample>,
    torque: Reader<TorqueSample>,
    pub(super) log: ValveLog,
    dir: PathBuf,
    config: Option<PathBuf>,
    cascade: bool,
    current: Option<SwapInProgress>,
    handover_seq: u64,
    event_seq: u64,
    /// The newest reading from which the valve's own timeout held it
    /// neutral (the plant says so): how soon the valve was safe when the
    /// valve process itself was gone.
    amplifier_neutral_from: Option<u64>,
    /// The valve's newest neutral for silence (no reading, no command): its
    /// reading and when, by the valve's clock.
    last_silence: Option<(u64, u64)>,
    period_ns: u64,
    /// The loop's tracking error, by reading: a swap is judged by it.
    tracking: TrackingLog,
    judge: SwapJudge,
}

/// How a swap is judged by the tracking that follows it
/// (`[supervisor] swap_judge_ms`, `swap_rollback_factor`,
/// `swap_rollback_min_rms_rad`).
#[derive(Debug, Clone, Copy)]
pub(super) struct SwapJudge {
    /// Readings watched after the switch, compared with as many before;
    /// 0: a swap is not judged.
    pub(super) readings: u64,
    pub(super) factor: f64,
    pub(super) floor_rad: f64,
    /// A fallback is judged from this many readings after its first answer.
    pub(super) fallback_settle_readings: u64,
}

/// A swap that undoes the one before: what it undoes, and why.
#[derive(Debug, Clone, Copy)]
struct Undoing {
    /// The variant swapped away from again.
    variant: &'static str,
    rms_after: f64,
    rms_before: f64,
}

struct SwapInProgress {
    index: usize,
    stage: u32,
    from: &'static str,
    to: &'static str,
    child: Supervised,
    request: PendingCommand<SupervisorRequest, SupervisorReply>,
    standby_outputs: u32,
    phase: SwapPhase,
    undoing: Option<Undoing>,
}

enum SwapPhase {
    Starting {
        since: Instant,
    },
    HandedOver {
        at_seq: u64,
        since: Instant,
        handover_seq: u64,
        /// The new process acknowledged the handover.
        taken: bool,
        /// The one it replaces acknowledged too.
        retired: bool,
        /// The stage's output for a reading from `at_seq` on came from the
        /// new variant.
        in_charge: bool,
    },
    /// Done; the tracking that follows is watched before the answer.
    Judging {
        at_seq: u64,
        since: Instant,
        /// The answer had the swap not been judged.
        message: String,
        quality: SwitchQuality,
    },
}

/// Readings between the handover being published and the switch: 20 ms,
/// ample for both processes to read it.
pub(super) const HANDOVER_LEAD: u64 = 20;
/// Standby outputs required before a handover: it has tracked for 100 ms.
const STANDBY_OUTPUTS: u32 = 100;

impl Swaps {
    pub(super) fn open(
        bus: &Bus,
        dir: PathBuf,
        config: Option<PathBuf>,
        cascade: bool,
        period: Duration,
        judge: SwapJudge,
    ) -> Result<Self> {
        Ok(Self {
            handovers: Outlet::open(bus, service::HANDOVER)?,
            events: Outlet::open(bus, service::SUPERVISOR_EVENTS)?,
            valve: Reader::open(bus, service::VALVE, 256)?,
            standby_position: Reader::open(bus, service::POSITION_STANDBY, 256)?,
            standby_torque: Reader::open(bus, service::TORQUE_STANDBY, 256)?,
            acks: Reader::open(bus, service::HANDOVER_ACK, 64)?,
            position: Reader::open(bus, service::POSITION, 256)?,
            torque: Reader::open(bus, service::TORQUE, 256)?,
            log: ValveLog::with_capacity(4096),
            dir,
            config,
            cascade,
            current: None,
            handover_seq: 0,
            event_seq: 0,
            amplifier_neutral_from: None,
            last_silence: None,
            period_ns: period.as_nanos().max(1) as u64,
            // Twice the watched readings: as many before the switch; a
            // fallback's settle besides.
            tracking: TrackingLog::with_capacity((2 * judge.readings + judge.fallback_settle_readings + 1000) as usize),
            judge,
        })
    }

    pub(super) fn tick(
        &mut self,
        scope: &RunScope,
        children: &mut [Supervised],
        request: Option<PendingCommand<SupervisorRequest, SupervisorReply>>,
        reading: Option<u64>,
        now: Instant,
    ) -> Result<()> {
        self.take_valve_samples()?;
        // The outer loop's samples: the tracking error, and whether the
        // new variant answers (a position swap's handover).
        let handed_over = self.current.as_ref().and_then(|swap| match swap.phase {
            SwapPhase::HandedOver { at_seq, .. } if swap.stage == code::STAGE_POSITION => {
                Some((at_seq, code::variant_code(swap.to).unwrap_or(u32::MAX)))
            }
            _ => None,
        });
        let mut position_answered_by_new = false;
        while let Some(p) = self.position.next()? {
            self.tracking.push(p.sensor_seq, p.reference_angle - p.angle);
            position_answered_by_new |= handed_over.is_some_and(|(at, v)| p.sensor_seq >= at && p.variant == v);
        }
        let mut standby_outputs = 0;
        while self.standby_position.next()?.is_some() {
            standby_outputs += 1;
        }
        while self.standby_torque.next()?.is_some() {
            standby_outputs += 1;
        }
        if let Some(request) = request {
            match self.current {
                Some(_) => reply(
                    request,
                    false,
                    0,
                    "a swap is already under way; try again when it is done",
                )?,
                None => self.begin(scope, children, request)?,
            }
        }
        let Some(mut swap) = self.current.take() else {
            return Ok(());
        };
        swap.standby_outputs += standby_outputs;
        match swap.phase {
            SwapPhase::Starting { since } => {
                if swap.child.reap() {
                    return self.fail(
                        swap,
                        "it exited while starting (its error is above, on the supervisor's stderr)",
                    );
                }
                if now.saturating_duration_since(since) > Duration::from_secs(5) {
                    swap.child.kill_hung();
                    return self.fail(swap, "it gave no output within 5 s");
                }
                match reading {
                    Some(seq) if swap.standby_outputs >= STANDBY_OUTPUTS => {
                        let at_seq = seq + HANDOVER_LEAD;
                        let handover_seq = self.hand_over(
                            swap.stage,
                            at_seq,
                            swap.child.pid().unwrap_or(0),
                            code::variant_code(swap.to).unwrap_or(0),
                        )?;
                        swap.phase = SwapPhase::HandedOver {
                            at_seq,
                            since: now,
                            handover_seq,
                            taken: false,
                            retired: false,
                            in_charge: false,
                        };
                    }
                    _ => {}
                }
                self.current = Some(swap);
            }
            SwapPhase::HandedOver {
                at_seq,
                since,
                handover_seq,
                mut taken,
                mut retired,
                mut in_charge,
            } => {
                let new_pid = swap.child.pid().unwrap_or(0);
                while let Some(ack) = self.acks.next()? {
                    if ack.handover_seq == handover_seq {
                        taken |= ack.taking == 1 && ack.pid == new_pid;
                        retired |= ack.taking == 0;
                    }
                }
                let new_variant = code::variant_code(swap.to).unwrap_or(u32::MAX);
                let answered_by_new = |seq: u64, variant: u32| seq >= at_seq && variant == new_variant;
                in_charge |= position_answered_by_new;
                while let Some(t) = self.torque.next()? {
                    in_charge |= swap.stage == code::STAGE_TORQUE && answered_by_new(t.sensor_seq, t.variant);
                }
                let judged = self.log.judge(at_seq, 20, 1000, 1000);
                let timed_out = now.saturating_duration_since(since) > Duration::from_secs(5);
                if !timed_out && (judged.is_none() || !taken || !in_charge) {
                    swap.phase = SwapPhase::HandedOver {
                        at_seq,
                        since,
                        handover_seq,
                        taken,
                        retired,
                        in_charge,
                    };
                    self.current = Some(swap);
                    return Ok(());
                }
                if !(taken && in_charge) {
                    // Not in charge: the old process, if it retired, is
                    // found silent and restarted as a hung one would be.
                    swap.child.kill_hung();
                    let why = if taken {
                        format!("it acknowledged the handover but answered no reading from {at_seq} within 5 s")
                    } else {
                        "it did not acknowledge the handover within 5 s".to_owned()
                    };
                    return self.fail(swap, &why);
                }
                if !retired {
                    tracing::warn!(
                        "the {} process replaced by {} did not acknowledge its retirement; it is stopped",
                        swap.from,
                        swap.to
                    );
                }
                let quality = judged.unwrap_or(SwitchQuality {
                    missed_cycles: 120,
                    command_step: 1.0,
                    loop_step_before: 0.0,
                    loop_step_after: 0.0,
                });
                // The new process takes the old one's place: its restarts,
                // its pid history; the old one has stopped answering.
                let old = &mut children[swap.index];
                swap.child.restarts = old.restarts;
                swap.child.pids.splice(0..0, old.pids.iter().copied());
                swap.child.last_output = now;
                std::mem::swap(old, &mut swap.child);
                swap.child.request_stop();
                swap.child.finish_stop(now + Duration::from_secs(1));
                self.publish_event(EventKind::Swap, &swap, at_seq, quality)?;
                if let Some(undone) = swap.undoing {
                    let message = format!(
                        "rolled back: {} runs {} again from reading {at_seq} ({} missed cycles); {} tracked {:.4} rad rms against {:.4} before",
                        code::stage_name(swap.stage),
                        swap.to,
                        quality.missed_cycles,
                        undone.variant,
                        undone.rms_after,
                        undone.rms_before,
                    );
                    tracing::warn!("{message}");
                    return reply(
                        swap.request,
                        false,
                        code::variant_code(undone.variant).unwrap_or(0),
                        &message,
                    );
                }
                let message = format!(
                    "{} now runs {} (was {}) from reading {at_seq}: {} missed cycles, command step {:.2}% of its range (the loop's own steps: {:.2}% before, {:.2}% after)",
                    code::stage_name(swap.stage),
                    swap.to,
                    swap.from,
                    quality.missed_cycles,
                    quality.command_step * 100.0,
                    quality.loop_step_before * 100.0,
                    quality.loop_step_after * 100.0
                );
                if self.judge.readings == 0 {
                    return answer(swap, quality, &message);
                }
                swap.phase = SwapPhase::Judging {
                    at_seq,
                    since: now,
                    message,
                    quality,
                };
                self.current = Some(swap);
            }
            SwapPhase::Judging {
                at_seq,
                since,
                ref message,
                quality,
            } => {
                let until = at_seq + self.judge.readings;
                let seen = self.tracking.newest().is_some_and(|newest| newest >= until);
                // A loop that stopped answering is the fault watch's: the
                // swap is judged on what came.
                let waited_long = now.saturating_duration_since(since)
                    > Duration::from_nanos(self.period_ns.saturating_mul(2 * self.judge.readings));
                if !seen && !waited_long {
                    self.current = Some(swap);
                    return Ok(());
                }
                let before = self
                    .tracking
                    .rms_between(at_seq.saturating_sub(self.judge.readings), at_seq);
                let after = self.tracking.rms_between(at_seq, until);
                let (Some((rms_before, _)), Some((rms_after, _))) = (before, after) else {
                    let message =
                        format!("{message}; its tracking not judged: no outer-loop samples around the switch");
                    return answer(swap, quality, &message);
                };
                if !worse_enough(rms_before, rms_after, self.judge.factor, self.judge.floor_rad) {
                    let message = format!("{message}; tracking {rms_after:.4} rad rms after, {rms_before:.4} before");
                    return answer(swap, quality, &message);
                }
                tracing::warn!(
                    "{} tracks {rms_after:.4} rad rms after the swap against {rms_before:.4} before: swapping back to {}",
                    swap.to,
                    swap.from
                );
                let undoing = Undoing {
                    variant: swap.to,
                    rms_after,
                    rms_before,
                };
                let mut child = Supervised::new(code::stage_name(swap.stage), &self.dir, self.config.clone());
                child.variant = Some(swap.from);
                if let Err(e) = child.spawn(scope, &["--standby".to_owned()]) {
                    let message = format!(
                        "{message}; it tracks {rms_after:.4} rad rms against {rms_before:.4} before, and the {} process to swap back to cannot start: {e:#}",
                        swap.from
                    );
                    return reply(swap.request, false, code::variant_code(swap.to).unwrap_or(0), &message);
                }
                self.current = Some(SwapInProgress {
                    index: swap.index,
                    stage: swap.stage,
                    from: swap.to,
                    to: swap.from,
                    child,
                    request: swap.request,
                    standby_outputs: 0,
                    phase: SwapPhase::Starting { since: now },
                    undoing: Some(undoing),
                });
            }
        }
        Ok(())
    }

    fn begin(
        &mut self,
        scope: &RunScope,
        children: &[Supervised],
        request: PendingCommand<SupervisorRequest, SupervisorReply>,
    ) -> Result<()> {
        let asked = request.request();
        let SwapTarget { index, name, to } = match swap_target(asked.stage, asked.variant, self.cascade) {
            Ok(target) => target,
            Err(why) => return reply(request, false, 0, &why),
        };
        let from = children[index].variant.unwrap_or("?");
        if from == to {
            return reply(
                request,
                false,
                code::variant_code(from).unwrap_or(0),
                &format!("{name} already runs {to}"),
            );
        }
        if !children[index].is_running() {
            return reply(
                request,
                false,
                0,
                &format!("{name} is not running (restarting?): try again"),
            );
        }
        let mut child = Supervised::new(name, &self.dir, self.config.clone());
        child.variant = Some(to);
        if let Err(e) = child.spawn(scope, &["--standby".to_owned()]) {
            return reply(
                request,
                false,
                0,
                &format!("cannot start the {to} {name} process: {e:#}"),
            );
        }
        self.current = Some(SwapInProgress {
            index,
            stage: asked.stage,
            from,
            to,
            child,
            request,
            standby_outputs: 0,
            phase: SwapPhase::Starting { since: Instant::now() },
            undoing: None,
        });
        Ok(())
    }

    /// Names the process that answers `stage` from reading `at_seq` on.
    /// Returns the handover's number, which the acknowledgements carry.
    pub(super) fn hand_over(&mut self, stage: u32, at_seq: u64, new_pid: u32, variant: u32) -> Result<u64> {
        let seq = self.handover_seq;
        self.handovers.publish(Handover {
            seq,
            stage_time_ns: clock::now_ns(),
            at_seq,
            new_pid,
            stage,
            variant,
            reserved: 0,
        })?;
        self.handover_seq += 1;
        Ok(seq)
    }

    /// The running controller stays in charge; the caller hears why.
    fn fail(&mut self, swap: SwapInProgress, why: &str) -> Result<()> {
        let quality = SwitchQuality {
            missed_cycles: 0,
            command_step: 0.0,
            loop_step_before: 0.0,
            loop_step_after: 0.0,
        };
        self.publish_event(EventKind::SwapFailed, &swap, 0, quality)?;
        let message = format!(
            "the {} {} process did not take over, {why}; {} stays in charge",
            swap.to,
            code::stage_name(swap.stage),
            swap.from
        );
        reply(
            swap.request,
            false,
            code::variant_code(swap.from).unwrap_or(0),
            &message,
        )
    }

    /// Moves the valve's waiting samples into the log.
    fn take_valve_samples(&mut self) -> Result<()> {
        while let Some(v) = self.valve.next()? {
            self.log.push(v.sensor_seq, v.command, v.faults);
            // Neutral on the valve's own clock, answering no command.
            if v.faults & hydractl_samples::fault::STALE != 0 && v.requested.is_nan() {
                self.last_silence = Some((v.sensor_seq, v.stage_time_ns));
            }
        }
        Ok(())
    }

    /// How many periods the valve held its last command after the fault's
    /// process last answered, before it went safe: by the valve's samples,
    /// or by its own timeout when the valve process was the one gone,
    /// whichever came first. Taken while the valve's recent samples still
    /// hold the fault (a process down for seconds outlasts them).
    pub(super) fn valve_safe_after(&mut self, fault: &Fault) -> Option<u64> {
        // The valve's samples up to now, not up to the last tick: a tick
        // that came late (the supervisor shares its CPU with the recorder
        // and everything else) must not hide the valve's going safe.
        self.take_valve_samples().ok()?;
        let seq = fault.last_seq?;
        let by_amplifier = self
            .amplifier_neutral_from
            .filter(|&from| from > seq)
            .map(|from| from.saturating_sub(seq + 2));
        match (self.log.valve_safe_after_periods(seq), by_amplifier) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (None, None) => {
                // No reading came after its last (the plant itself gone, or
                // every stage starved): the valve's silence timeout made it
                // safe, counted in periods of the loop's time.
                let last_output_ns = clock::now_ns()
                    .saturating_sub(fault.detected_at.elapsed().as_nanos() as u64)
                    .saturating_sub(fault.silent_for.as_nanos() as u64);
                self.last_silence
                    .filter(|&(at, time_ns)| at >= seq && time_ns > last_output_ns)
                    .map(|(_, time_ns)| ((time_ns - last_output_ns) / self.period_ns).saturating_sub(1))
            }
            (a, b) => a.or(b),
        }
    }

    /// The loop's tracking error by reading, and how a change is judged
    /// by it: what a fallback is judged by too.
    pub(super) fn tracking(&self) -> (&TrackingLog, &SwapJudge, Duration) {
        (&self.tracking, &self.judge, Duration::from_nanos(self.period_ns))
    }

    /// A fallback judged: `to` is what runs now ("" for nothing).
    pub(super) fn publish_judged_fallback(
        &mut self,
        stage: &str,
        (from, to): (&str, &str),
        at_seq: u64,
        (rms_before, rms_after): (f64, f64),
    ) -> Result<()> {
        self.publish(SupervisorEvent {
            sensor_seq: at_seq,
            tracking_rms_before_rad: rms_before,
            tracking_rms_after_rad: rms_after,
            valve_safe_after_periods: u64::MAX,
            restarted_after_ns: u64::MAX,
            kind: EventKind::FallbackJudged.code(),
            process: fixed_name(stage),
            from: fixed_name(from),
            to: fixed_name(to),
            ..SupervisorEvent::default()
        })
    }

    /// An event, numbered and stamped now.
    fn publish(&mut self, event: SupervisorEvent) -> Result<()> {
        self.events.publish(SupervisorEvent {
            seq: self.event_seq,
            stage_time_ns: clock::now_ns(),
            ..event
        })?;
        self.event_seq += 1;
        Ok(())
    }

    /// The new process of a swap under way.
    pub(super) fn standby_pid(&self) -> Option<u32> {
        self.current.as_ref().and_then(|swap| swap.child.pid())
    }

    /// The plant's newest reading: whether the valve's own timeout holds it neutral.
    pub(super) fn note_reading(&mut self, reading: &hydractl_samples::PlantReading) {
        if reading.amplifier_neutral_for > 0 {
            self.amplifier_neutral_from =
                Some(reading.sensor_seq - u64::from(reading.amplifier_neutral_for).min(reading.sensor_seq));
        }
    }

    /// A fault's account, once its process answers again: how long the
    /// detection, the valve's going safe and the restart took.
    pub(super) fn publish_fault(&mut self, process: &str, fault: Fault, back_at: Option<Instant>) -> Result<()> {
        let valve_safe = fault
            .valve_safe_after
            .or_else(|| self.valve_safe_after(&fault))
            .unwrap_or(u64::MAX);
        self.publish(SupervisorEvent {
            sensor_seq: fault.last_seq.unwrap_or(0),
            valve_safe_after_periods: valve_safe,
            detected_after_ns: fault.silent_for.as_nanos() as u64,
            restarted_after_ns: back_at.map_or(u64::MAX, |at| {
                at.saturating_duration_since(fault.detected_at).as_nanos() as u64
            }),
            kind: fault.kind.code(),
            pid: fault.pid,
            process: fixed_name(process),
            from: fixed_name(fault.variants.map_or("", |v| v.0)),
            to: fixed_name(fault.variants.map_or("", |v| v.1)),
            ..SupervisorEvent::default()
        })
    }

    /// The plant seat changed: fallback or asked for.
    pub(super) fn publish_plant_event(
        &mut self,
        kind: EventKind,
        at_seq: u64,
        detected_after: Duration,
        process: &str,
        (from, to): (&str, &str),
        pid: u32,
    ) -> Result<()> {
        self.publish(SupervisorEvent {
            sensor_seq: at_seq,
            valve_safe_after_periods: u64::MAX,
            detected_after_ns: detected_after.as_nanos() as u64,
            restarted_after_ns: u64::MAX,
            kind: kind.code(),
            pid,
            process: fixed_name(process),
            from: fixed_name(from),
            to: fixed_name(to),
            ..SupervisorEvent::default()
        })
    }

    fn publish_event(
        &mut self,
        kind: EventKind,
        swap: &SwapInProgress,
        at_seq: u64,
        quality: SwitchQuality,
    ) -> Result<()> {
        self.publish(SupervisorEvent {
            sensor_seq: at_seq,
            missed_cycles: quality.missed_cycles,
            command_step: quality.command_step,
            loop_step_before: quality.loop_step_before,
            loop_step_after: quality.loop_step_after,
            kind: kind.code(),
            pid: swap.child.pid().unwrap_or(0),
            process: fixed_name(code::stage_name(swap.stage)),
            from: fixed_name(swap.from),
            to: fixed_name(swap.to),
            ..SupervisorEvent::default()
        })
    }
}

/// A swap done and kept: the caller hears how it went.
fn answer(swap: SwapInProgress, quality: SwitchQuality, message: &str) -> Result<()> {
    Ok(swap.request.reply(SupervisorReply {
        command_step: quality.command_step,
        missed_cycles: quality.missed_cycles,
        accepted: 1,
        from_variant: code::variant_code(swap.from).unwrap_or(0),
        message: fixed_name(message),
    })?)
}

pub(super) fn reply(
    request: PendingCommand<SupervisorRequest, SupervisorReply>,
    accepted: bool,
    from_variant: u32,
    message: &str,
) -> Result<()> {
    Ok(request.reply(SupervisorReply {
        accepted: u32::from(accepted),
        from_variant,
        message: fixed_name(message),
        ..SupervisorReply::default()
    })?)
}

/// The controller a swap request names.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct SwapTarget {
    /// Its place in the pipeline.
    index: usize,
    name: &'static str,
    /// The variant asked for.
    to: &'static str,
}

/// What a swap request asks for, or why it cannot be done: a stage that
/// has no variants, a variant the stage does not have, or the torque stage
/// when it is bypassed (position-only control).
fn swap_target(stage: u32, variant: u32, cascade: bool) -> Result<SwapTarget, String> {
    let (index, name) = match stage {
        code::STAGE_POSITION => (3, "position"),
        code::STAGE_TORQUE => (4, "torque"),
        other => return Err(format!("no stage {other}: swap `position` or `torque`")),
    };
    let to = match (stage, code::variant_name(variant)) {
        (code::STAGE_POSITION, v @ ("pid" | "mfc")) => v,
        (code::STAGE_TORQUE, v @ ("pid" | "hinf")) => v,
        (_, v) => {
            let allowed = if stage == code::STAGE_POSITION {
                "pid or mfc"
            } else {
                "pid or hinf"
            };
            return Err(format!("{name} has no variant `{v}`: {allowed}"));
        }
    };
    if stage == code::STAGE_TORQUE && !cascade {
        return Err("the torque stage is bypassed in position-only control: nothing to swap".to_owned());
    }
    Ok(SwapTarget { index, name, to })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn variant(name: &str) -> u32 {
        code::variant_code(name).expect("a variant")
    }

    #[test]
    fn a_swap_names_a_stage_with_variants_and_one_of_its_variants() {
        assert_eq!(
            swap_target(code::STAGE_POSITION, variant("mfc"), false),
            Ok(SwapTarget {
                index: 3,
                name: "position",
                to: "mfc"
            })
        );
        assert_eq!(
            swap_target(code::STAGE_TORQUE, variant("hinf"), true),
            Ok(SwapTarget {
                index: 4,
                name: "torque",
                to: "hinf"
            })
        );
        let refused = |stage, v, cascade| swap_target(stage, v, cascade).expect_err("refused");
        assert!(refused(code::STAGE_POSITION, variant("hinf"), true).contains("position has no variant `hinf`"));
        assert!(refused(code::STAGE_TORQUE, variant("mfc"), true).contains("pid or hinf"));
        assert!(refused(code::STAGE_TORQUE, variant("pid"), false).contains("bypassed"));
        assert!(refused(code::STAGE_PLANT, variant("pid"), true).contains("swap `position` or `torque`"));
    }
}
