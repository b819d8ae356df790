//! The watchdog: starts every process of the loop, restarts a crashed or
//! hung one with back-off after cleaning its stale iceoryx2 resources,
//! publishes the status of all, and on SIGTERM or SIGINT stops them and
//! removes every file of the run.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{bail, Result};
use hydractl_bus::{clock, run_loop, Bus, CommandServer, Outlet, PendingCommand, Reader, RunScope};
use hydractl_config::{PositionVariant, Structure, TorqueVariant};
use hydractl_processes::supervision::{Supervised, PIPELINE};
use hydractl_processes::swap::{SwitchQuality, ValveLog};
use hydractl_processes::SplitArgs;
use hydractl_samples::{
    code, fault, fixed_name, service, source, FrictionSample, Handover, PlantReading, PositionSample, ProcessStatus,
    RecorderStatus, SensorSample, SupervisorEvent, SupervisorReply, SupervisorRequest, SupervisorStatus, TorqueSample,
    ValveSample, MAX_PROCESSES,
};

/// The newest sequence number seen on each pipeline service.
struct Heartbeats {
    plant: Reader<PlantReading>,
    sensor: Reader<SensorSample>,
    friction: Reader<FrictionSample>,
    position: Reader<PositionSample>,
    torque: Reader<TorqueSample>,
    valve: Reader<ValveSample>,
}

impl Heartbeats {
    fn open(bus: &Bus) -> Result<Self> {
        Ok(Self {
            plant: Reader::open(bus, service::PLANT_READING, 4)?,
            sensor: Reader::open(bus, service::SENSOR, 4)?,
            friction: Reader::open(bus, service::FRICTION, 4)?,
            position: Reader::open(bus, service::POSITION, 4)?,
            torque: Reader::open(bus, service::TORQUE, 4)?,
            valve: Reader::open(bus, service::VALVE, 4)?,
        })
    }

    /// The newest reading each of the pipeline's outputs answered since the
    /// last call (`None`: it did not advance), in [`PIPELINE`] order; keeps
    /// the plant's last reading for a restart.
    fn advanced(
        &self,
        last_reading: &mut Option<PlantReading>,
        position_output_finite: &mut bool,
    ) -> Result<[Option<Answer>; 6]> {
        let reading = self.plant.newest_by(|r| r.sensor_seq)?;
        if reading.is_some() {
            *last_reading = reading;
        }
        let position = self.position.latest()?;
        if let Some(p) = position {
            *position_output_finite = p.output.is_finite();
        }
        Ok([
            reading.map(|r| Answer::new(r.sensor_seq, r.sensor_time_ns)),
            self.sensor
                .latest()?
                .map(|s| Answer::new(s.sensor_seq, s.stage_time_ns)),
            self.friction
                .latest()?
                .map(|s| Answer::new(s.sensor_seq, s.stage_time_ns)),
            position.map(|s| Answer::new(s.sensor_seq, s.stage_time_ns)),
            self.torque
                .latest()?
                .map(|s| Answer::new(s.sensor_seq, s.stage_time_ns)),
            self.valve.latest()?.map(|s| Answer::new(s.sensor_seq, s.stage_time_ns)),
        ])
    }
}

/// A process's newest output: the reading it answered, and when.
#[derive(Debug, Clone, Copy)]
struct Answer {
    seq: u64,
    time_ns: u64,
}

impl Answer {
    fn new(seq: u64, time_ns: u64) -> Self {
        Self { seq, time_ns }
    }
}

fn main() -> Result<()> {
    let started = hydractl_processes::start("supervisor")?;
    let scope = started.bus.scope().clone();
    let policy = started.config.supervisor.clone();
    // For the whole run: the loop's stages wake at every hop, and nothing
    // but the loop should take its CPU.
    let timing = &started.config.timing;
    let (_reservation, refusals) = hydractl_bus::placement::reserve_for_run(
        timing.loop_cpu,
        timing.cpu_dma_latency_us,
        timing.interrupts_off_loop_cpu,
    );
    for e in refusals {
        eprintln!("supervisor: {e}");
    }
    // Over what a crashed run left: its dead nodes (its files, when nothing
    // of it was alive, `hydractl run` removed before starting us).
    scope.remove_dead_nodes()?;
    let dir = hydractl_bus::binary_dir()?;
    let mut children: Vec<Supervised> = PIPELINE
        .iter()
        .map(|(name, _, _)| Supervised::new(name, &dir, started.args.config.clone()))
        .collect();
    // With a machine, it holds the plant seat and the simulated plant waits
    // as its spare.
    let mut seat = Seat::open(&started.bus, &started.config)?;
    if started.config.machine.is_some() {
        let machine = Supervised::new("machine", &dir, started.args.config.clone());
        seat.spare = Some(std::mem::replace(&mut children[0], machine));
        seat.source = source::MACHINE;
    }
    let cascade = started.config.control.structure == Structure::Cascade;
    children[3].variant = Some(match started.config.control.outer().variant {
        PositionVariant::Pid => "pid",
        PositionVariant::Mfc => "mfc",
    });
    // In position-only control the torque stage passes the command through.
    children[4].variant = cascade.then_some(match started.config.control.torque_variant {
        TorqueVariant::Pid => "pid",
        TorqueVariant::Hinf => "hinf",
    });
    let mut swaps = Swaps::open(&started.bus, dir.clone(), started.args.config.clone(), cascade)?;
    let mut recorder = started.args.record.out.as_ref().map(|out| RecorderChild {
        child: Supervised::new("recorder", &dir, started.args.config.clone()),
        split: started.args.record.split.clone(),
        out: out.clone(),
    });
    let outcome = match &mut recorder {
        Some(r) => r.start(&started.bus, &scope),
        None => Ok(()),
    }
    .and_then(|()| {
        supervise(
            &started.bus,
            &scope,
            &policy,
            &mut children,
            &mut recorder,
            &mut swaps,
            &mut seat,
        )
    });

    // Stop the loop, then the recorder, which drains what the loop last
    // published and finishes its file; then clean what is left.
    let deadline = Instant::now() + Duration::from_millis(policy.stop_timeout_ms);
    for child in children.iter().rev() {
        child.request_stop();
    }
    if let Some(spare) = &seat.spare {
        spare.request_stop();
    }
    for child in children.iter_mut().rev() {
        child.finish_stop(deadline);
    }
    if let Some(spare) = &mut seat.spare {
        spare.finish_stop(deadline);
    }
    if let Some(r) = &mut recorder {
        r.child.request_stop();
        // Finishing a file (its last chunk, summary and indexes) takes longer
        // than a control process's stop.
        r.child.finish_stop(Instant::now() + Duration::from_secs(10));
    }
    // Ports before their node: a port keeps its node alive.
    drop(swaps);
    drop(seat);
    drop(started.bus);
    // Clean up whatever the outcome; report the outcome's error first.
    let cleaned = scope.clean_stale();
    outcome.and(cleaned.map_err(Into::into))
}

/// The recorder, when the run records: started before the loop, so that
/// the loop's first samples are recorded, and stopped after it.
struct RecorderChild {
    child: Supervised,
    split: SplitArgs,
    out: PathBuf,
}

impl RecorderChild {
    /// Starts the recorder and waits until it is subscribed (its first
    /// status); a recorder that dies first (an unwritable file, say) fails
    /// the run, having said why on stderr.
    fn start(&mut self, bus: &Bus, scope: &RunScope) -> Result<()> {
        let ready: Reader<RecorderStatus> = Reader::open(bus, service::RECORDER_STATUS, 4)?;
        self.child.spawn(scope, &self.split.recorder_args(&self.out)?)?;
        let deadline = Instant::now() + Duration::from_secs(10);
        while Instant::now() < deadline {
            if ready.latest()?.is_some() {
                return Ok(());
            }
            if self.child.reap() {
                bail!(
                    "the recorder exited before it started recording to {}",
                    self.out.display()
                );
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        bail!("the recorder did not start within 10 s")
    }

    /// A restarted recorder writes a new file beside the first:
    /// `STEM_restartN.mcap`, so that nothing recorded is overwritten.
    fn restart(&mut self, scope: &RunScope) -> Result<()> {
        let n = self.child.restarts + 1;
        let stem = self
            .out
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        let out = self.out.with_file_name(format!("{stem}_restart{n}.mcap"));
        self.child.spawn(scope, &self.split.recorder_args(&out)?)?;
        self.child.restarts = n;
        Ok(())
    }
}

fn supervise(
    bus: &Bus,
    scope: &RunScope,
    policy: &hydractl_config::SupervisorConfig,
    children: &mut [Supervised],
    recorder: &mut Option<RecorderChild>,
    swaps: &mut Swaps,
    seat: &mut Seat,
) -> Result<()> {
    for child in children.iter_mut() {
        child.spawn(scope, &[])?;
    }
    if let Some(spare) = &mut seat.spare {
        spare.spawn(scope, &["--standby".to_owned()])?;
    }
    let commands: CommandServer<SupervisorRequest, SupervisorReply> =
        CommandServer::open(bus, service::SUPERVISOR_COMMAND)?;
    let mut last_reading: Option<PlantReading> = None;
    let heartbeats = Heartbeats::open(bus)?;
    let status: Outlet<SupervisorStatus> = Outlet::open(bus, service::SUPERVISOR_STATUS)?;
    let hung_after = Duration::from_millis(policy.hung_after_ms);
    // A (re)started process gets this long to open its ports.
    let startup_grace = Duration::from_millis(500);
    let own_pid = std::process::id();
    let mut last_status = Instant::now();
    let mut status_seq = 0u64;
    // A fault is published once its process is back (or given up on), with
    // how long each step took.
    let mut faults: Vec<Option<Fault>> = vec![None; children.len()];
    let mut last_answer_ns = vec![clock::now_ns(); children.len()];
    let mut restarting = vec![true; children.len()];
    let mut position_output_finite = true;
    // The newest rejected command already acted on.
    let mut misbehaving_handled: Option<u64> = None;
    let mut failure = None;
    run_loop(&[], Some(Duration::from_millis(5)), bus, |_| {
        hydractl_bus::guarded(&mut failure, || -> Result<()> {
            let now = Instant::now();
            let advanced = heartbeats.advanced(&mut last_reading, &mut position_output_finite)?;
            // Whether each output had paused, before this round's news, by
            // its own timestamps (a just-restarted process has none yet).
            let now_ns = clock::now_ns();
            let mut paused = [false; PIPELINE.len()];
            for (p, last_ns) in paused.iter_mut().zip(&last_answer_ns) {
                *p = Duration::from_nanos(now_ns.saturating_sub(*last_ns)) >= hung_after / 2;
            }
            for i in 0..children.len() {
                if let Some(answer) = advanced[i] {
                    children[i].last_output = now;
                    children[i].last_seq = Some(answer.seq);
                    last_answer_ns[i] = answer.time_ns;
                    // Back after a fault: the fault's account is complete.
                    if let Some(fault) = faults[i].take() {
                        swaps.publish_fault(children[i].name, fault, Some(now))?;
                    }
                }
                // Input back after a pause: measure a hang from now on.
                if i > 0 && advanced[i - 1].is_some() && paused[i - 1] {
                    children[i].input_resumed = now;
                }
            }
            let mut cleanup_needed = false;
            // The machine lost (dead, or its readings stopped): the simulated
            // plant takes the seat before anything else is judged.
            if seat.can_fall_back() {
                let silent_for = Duration::from_nanos(clock::now_ns().saturating_sub(last_answer_ns[0]));
                let crashed = children[0].reap();
                if crashed || (last_reading.is_some() && silent_for >= seat.lost_after) {
                    if crashed {
                        cleanup_needed = true;
                    }
                    let why = if crashed {
                        format!(
                            "the machine process exited; its last reading came {} ms before",
                            silent_for.as_millis()
                        )
                    } else {
                        format!("no reading from the machine for {} ms", silent_for.as_millis())
                    };
                    seat.fall_back(
                        children,
                        swaps,
                        last_reading.map(|r| r.sensor_seq),
                        silent_for,
                        &why,
                        now,
                    )?;
                    // The plant's own output clock stays where the machine
                    // left it: downstream waits for readings, not hung.
                    faults[0] = None;
                    if crashed {
                        if let Some(spare) = &mut seat.spare {
                            spare.after_stop(now, policy);
                        }
                    }
                }
            }
            cleanup_needed |= seat.tick_spare(scope, policy, now)?;
            // A controller whose commands the valve keeps rejecting (garbage,
            // or a limit cycle): the valve is already neutral; the controller
            // is restarted, into its fallback variant if the config names
            // one. The outer loop is blamed when its own output is garbage,
            // else the stage that feeds the valve.
            let rejected = swaps.log.rejected(
                fault::NOT_FINITE | fault::OUT_OF_RANGE | fault::LIMIT_CYCLE,
                2 * policy.misbehaving_after_periods,
                misbehaving_handled,
            );
            if rejected.count >= policy.misbehaving_after_periods {
                misbehaving_handled = rejected.newest;
                let i = if !position_output_finite || children[4].variant.is_none() {
                    3
                } else {
                    4
                };
                let child = &mut children[i];
                if child.is_running() {
                    let (kind, what) = if rejected.why & fault::LIMIT_CYCLE != 0 {
                        (code::EVENT_LIMIT_CYCLE, "limit-cycling")
                    } else {
                        (code::EVENT_MISBEHAVING, "garbage")
                    };
                    let from = child.variant;
                    if let Some(v) = policy
                        .fallback_variants
                        .get(child.name)
                        .and_then(|v| code::variant_code(v))
                    {
                        child.variant = Some(code::variant_name(v));
                    }
                    faults[i] = Some(Fault {
                        kind,
                        pid: child.pid().unwrap_or(0),
                        detected_at: now,
                        silent_for: Duration::ZERO,
                        last_seq: rejected.newest.map(|s| s.saturating_sub(rejected.count)),
                        variants: from.zip(child.variant),
                    });
                    child.kill_hung();
                    cleanup_needed = true;
                    eprintln!(
                        "supervisor: the valve rejected {} commands in {} readings as {what}: {} misbehaves; restarting it ({})",
                        rejected.count,
                        2 * policy.misbehaving_after_periods,
                        child.name,
                        child.variant.unwrap_or("-")
                    );
                    restarting[i] = child.after_stop(now, policy);
                }
            }
            for i in 0..children.len() {
                // Hung: running past its grace, its input flowing (the plant
                // paces itself), and no output for `hung_after`. The input
                // flows when its producer's outputs do, by their own
                // timestamps: a producer just restarted has none yet.
                let input_flowing = i == 0
                    || Duration::from_nanos(clock::now_ns().saturating_sub(last_answer_ns[i - 1])) < hung_after / 2;
                let child = &mut children[i];
                let quiet_since = child.last_output.max(child.input_resumed);
                // Silent since its last output's own timestamp: the
                // supervisor's tick would hide up to 5 ms of it.
                let (pid, silent_for, last_seq) = (
                    child.pid().unwrap_or(0),
                    Duration::from_nanos(clock::now_ns().saturating_sub(last_answer_ns[i])),
                    child.last_seq,
                );
                let fault = |kind| Fault {
                    kind,
                    pid,
                    detected_at: now,
                    silent_for,
                    last_seq,
                    variants: None,
                };
                if child.reap() {
                    faults[i] = Some(fault(code::EVENT_CRASH));
                    cleanup_needed = true;
                    restarting[i] = child.after_stop(now, policy);
                } else if child.is_running()
                    && child.uptime(now) > startup_grace
                    && input_flowing
                    && now.saturating_duration_since(quiet_since) > hung_after
                {
                    faults[i] = Some(fault(code::EVENT_HANG));
                    child.kill_hung();
                    cleanup_needed = true;
                    restarting[i] = child.after_stop(now, policy);
                }
            }
            // A process left down: its fault's account ends here.
            for i in 0..children.len() {
                if !std::mem::replace(&mut restarting[i], true) {
                    if let Some(fault) = faults[i].take() {
                        let why = children[i].given_up.clone().unwrap_or_default();
                        eprintln!("supervisor: {} is left down: {why}", children[i].name);
                        swaps.publish_fault(children[i].name, fault, None)?;
                    }
                }
            }
            if let Some(r) = recorder.as_mut() {
                if r.child.reap() {
                    cleanup_needed = true;
                    if !r.child.after_stop(now, policy) {
                        let why = r.child.given_up.clone().unwrap_or_default();
                        eprintln!("supervisor: the recorder is left down: {why}");
                    }
                }
            }
            if cleanup_needed {
                scope.remove_dead_nodes()?;
            }
            if let Some(r) = recorder.as_mut() {
                if r.child.restart_due(now) {
                    r.restart(scope)?;
                }
            }
            for child in children.iter_mut() {
                if child.restart_due(now) {
                    // A new plant goes on from the loop's last reading.
                    let args: Vec<String> = match (child.name, last_reading) {
                        ("plant", Some(r)) => vec![
                            "--resume".into(),
                            hydractl_processes::Resume {
                                seq: r.sensor_seq,
                                angle: r.true_angle,
                                p_a: r.p_a,
                                p_b: r.p_b,
                            }
                            .to_arg(),
                        ],
                        _ => Vec::new(),
                    };
                    child.spawn(scope, &args)?;
                    child.restarts += 1;
                }
            }
            let request = match commands.receive()? {
                Some(r) if r.request().stage == code::STAGE_PLANT => {
                    seat.on_request(r, children, swaps, last_reading.map(|r| r.sensor_seq), now)?;
                    None
                }
                other => other,
            };
            swaps.tick(scope, children, request, last_reading.map(|r| r.sensor_seq), now)?;
            if now.saturating_duration_since(last_status) >= Duration::from_millis(100) {
                last_status = now;
                let recorder = recorder.as_ref().map(|r| &r.child);
                status.publish(status_of(
                    status_seq, children, seat, recorder, own_pid, now, hung_after,
                ))?;
                status_seq += 1;
            }
            Ok(())
        })
    })?;
    failure.map_or(Ok(()), Err)
}

fn status_of(
    seq: u64,
    children: &[Supervised],
    seat: &Seat,
    recorder: Option<&Supervised>,
    own_pid: u32,
    now: Instant,
    hung_after: Duration,
) -> SupervisorStatus {
    let mut status = SupervisorStatus {
        seq,
        plant_is_simulation: u32::from(seat.source == source::SIMULATION),
        stage_time_ns: clock::now_ns(),
        ..SupervisorStatus::default()
    };
    let entries = children.iter().map(|c| ProcessStatus {
        name: fixed_name(c.name),
        variant: fixed_name(c.variant.unwrap_or(if c.name == "torque" { "bypassed" } else { "" })),
        pid: c.pid().unwrap_or(0),
        restarts: c.restarts,
        healthy: u32::from(c.is_running() && now.saturating_duration_since(c.last_output) <= hung_after),
        reserved: 0,
    });
    // The plant not in charge: the simulated plant is ready while it runs;
    // the machine is well while its readings come.
    let spare = seat.spare.as_ref().map(|p| ProcessStatus {
        name: fixed_name(p.name),
        variant: fixed_name("standby"),
        pid: p.pid().unwrap_or(0),
        restarts: p.restarts,
        healthy: u32::from(
            p.is_running() && (p.name == "plant" || now.saturating_duration_since(p.last_output) <= hung_after),
        ),
        reserved: 0,
    });
    // The recorder has no output of its own on the loop: healthy while it runs.
    let recorder = recorder.map(|r| ProcessStatus {
        name: fixed_name(r.name),
        variant: [0; 16],
        pid: r.pid().unwrap_or(0),
        restarts: r.restarts,
        healthy: u32::from(r.is_running()),
        reserved: 0,
    });
    let supervisor = ProcessStatus {
        name: fixed_name("supervisor"),
        variant: [0; 16],
        pid: own_pid,
        restarts: 0,
        healthy: 1,
        reserved: 0,
    };
    let mut count = 0;
    for (slot, entry) in status
        .processes
        .iter_mut()
        .zip(entries.chain(spare).chain(recorder).chain(std::iter::once(supervisor)))
    {
        *slot = entry;
        count += 1;
    }
    status.process_count = count.min(MAX_PROCESSES) as u32;
    status
}

/// The plant seat: which plant drives the loop's readings. With a machine,
/// the machine holds it and the simulated plant waits as the spare; when
/// the machine is lost, or on `hydractl plant sim|machine`, they change
/// places: `children[0]` is always the plant in charge.
struct Seat {
    source: u32,
    spare: Option<Supervised>,
    standby_readings: Reader<PlantReading>,
    lost_after: Duration,
}

impl Seat {
    fn open(bus: &Bus, config: &hydractl_config::Config) -> Result<Self> {
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
    fn can_fall_back(&self) -> bool {
        self.source == source::MACHINE && self.spare.as_ref().is_some_and(Supervised::is_running)
    }

    /// Keeps the spare: notes the machine's standby readings, restarts it
    /// as its rule says. Returns whether a dead node needs cleaning.
    fn tick_spare(
        &mut self,
        scope: &RunScope,
        policy: &hydractl_config::SupervisorConfig,
        now: Instant,
    ) -> Result<bool> {
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
                eprintln!("supervisor: the standby {} is left down: {why}", spare.name);
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
    fn fall_back(
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
        eprintln!(
            "supervisor: {why}: the loop now runs on the SIMULATED plant, from reading {at_seq} and the last measured state; `hydractl plant machine` goes back"
        );
        swaps.publish_plant_event(
            code::EVENT_FALLBACK,
            at_seq,
            silent_for,
            "machine",
            ("machine", "simulation"),
            pid,
        )
    }

    /// `hydractl plant sim|machine`: a live change of places, at a reading
    /// far enough ahead for both plants to see the handover.
    fn on_request(
        &mut self,
        request: PendingCommand<SupervisorRequest, SupervisorReply>,
        children: &mut [Supervised],
        swaps: &mut Swaps,
        reading: Option<u64>,
        now: Instant,
    ) -> Result<()> {
        let to = request.request().variant;
        let from = self.source;
        let refusal = if to != source::MACHINE && to != source::SIMULATION {
            Some(format!("no plant {to}: `sim` or `machine`"))
        } else if to == from {
            Some(format!("the loop already runs on the {}", plant_name(to)))
        } else if let Some(spare) = self.spare.as_ref().filter(|s| s.is_running()) {
            let quiet = now.saturating_duration_since(spare.last_output);
            if to == source::MACHINE && quiet > self.lost_after {
                Some(format!(
                    "the machine sends no readings (the last came {} ms ago): the loop stays on the simulated plant",
                    quiet.as_millis()
                ))
            } else if reading.is_none() {
                Some("the loop has no reading yet: try again".to_owned())
            } else {
                None
            }
        } else if self.spare.is_some() {
            Some(format!("the {} is not running: try again", plant_name(to)))
        } else {
            Some("this run has no machine (its config has no [machine]): it runs on the simulated plant".to_owned())
        };
        if let Some(why) = refusal {
            return reply(request, false, from, &why);
        }
        let at_seq = reading.unwrap_or(0) + HANDOVER_LEAD;
        let pid = self.spare.as_ref().and_then(Supervised::pid).unwrap_or(0);
        swaps.hand_over(code::STAGE_PLANT, at_seq, pid, to)?;
        self.change_places(children, now);
        self.source = to;
        let message = format!("the loop runs on the {} from reading {at_seq}", plant_name(to));
        eprintln!("supervisor: as asked, {message}");
        swaps.publish_plant_event(
            code::EVENT_PLANT_SWITCH,
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

fn plant_name(source_code: u32) -> &'static str {
    match source_code {
        source::MACHINE => "machine",
        _ => "simulation",
    }
}

/// A process that crashed or hung, until it is back.
#[derive(Debug, Clone, Copy)]
struct Fault {
    kind: u32,
    pid: u32,
    detected_at: Instant,
    /// From its last output to the detection.
    silent_for: Duration,
    /// The last reading it answered.
    last_seq: Option<u64>,
    /// A controller restarted for misbehaving: its variant, and the one it
    /// was restarted into.
    variants: Option<(&'static str, &'static str)>,
}

/// Hot swaps of the position or torque controller, asked for over
/// `hydractl/supervisor/command`: the new variant starts as a standby
/// process that tracks the running one; once it answers, a handover names
/// the reading from which it is in charge; the valve's samples around that
/// reading judge the switch; then the old process is stopped.
struct Swaps {
    handovers: Outlet<Handover>,
    events: Outlet<SupervisorEvent>,
    valve: Reader<ValveSample>,
    standby_position: Reader<PositionSample>,
    standby_torque: Reader<TorqueSample>,
    log: ValveLog,
    dir: PathBuf,
    config: Option<PathBuf>,
    cascade: bool,
    current: Option<SwapInProgress>,
    handover_seq: u64,
    event_seq: u64,
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
}

enum SwapPhase {
    Starting { since: Instant },
    HandedOver { at_seq: u64, since: Instant },
}

/// Readings between the handover being published and the switch: 20 ms,
/// ample for both processes to read it.
const HANDOVER_LEAD: u64 = 20;
/// Standby outputs required before a handover: it has tracked for 100 ms.
const STANDBY_OUTPUTS: u32 = 100;

impl Swaps {
    fn open(bus: &Bus, dir: PathBuf, config: Option<PathBuf>, cascade: bool) -> Result<Self> {
        Ok(Self {
            handovers: Outlet::open(bus, service::HANDOVER)?,
            events: Outlet::open(bus, service::SUPERVISOR_EVENTS)?,
            valve: Reader::open(bus, service::VALVE, 256)?,
            standby_position: Reader::open(bus, service::POSITION_STANDBY, 256)?,
            standby_torque: Reader::open(bus, service::TORQUE_STANDBY, 256)?,
            log: ValveLog::with_capacity(4096),
            dir,
            config,
            cascade,
            current: None,
            handover_seq: 0,
            event_seq: 0,
        })
    }

    fn tick(
        &mut self,
        scope: &RunScope,
        children: &mut [Supervised],
        request: Option<PendingCommand<SupervisorRequest, SupervisorReply>>,
        reading: Option<u64>,
        now: Instant,
    ) -> Result<()> {
        self.take_valve_samples()?;
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
                        self.hand_over(
                            swap.stage,
                            at_seq,
                            swap.child.pid().unwrap_or(0),
                            code::variant_code(swap.to).unwrap_or(0),
                        )?;
                        swap.phase = SwapPhase::HandedOver { at_seq, since: now };
                    }
                    _ => {}
                }
                self.current = Some(swap);
            }
            SwapPhase::HandedOver { at_seq, since } => {
                let judged = self.log.judge(at_seq, 20, 1000, 1000);
                let timed_out = now.saturating_duration_since(since) > Duration::from_secs(5);
                if judged.is_none() && !timed_out {
                    self.current = Some(swap);
                    return Ok(());
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
                self.publish_event(code::EVENT_SWAP, &swap, at_seq, quality)?;
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
                let from = code::variant_code(swap.from).unwrap_or(0);
                swap.request.reply(SupervisorReply {
                    command_step: quality.command_step,
                    missed_cycles: quality.missed_cycles,
                    accepted: 1,
                    from_variant: from,
                    message: fixed_name(&message),
                })?;
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
        let (index, name) = match asked.stage {
            code::STAGE_POSITION => (3, "position"),
            code::STAGE_TORQUE => (4, "torque"),
            other => {
                return reply(
                    request,
                    false,
                    0,
                    &format!("no stage {other}: swap `position` or `torque`"),
                )
            }
        };
        let to = match (asked.stage, code::variant_name(asked.variant)) {
            (code::STAGE_POSITION, v @ ("pid" | "mfc")) => v,
            (code::STAGE_TORQUE, v @ ("pid" | "hinf")) => v,
            (_, v) => {
                let allowed = if asked.stage == code::STAGE_POSITION {
                    "pid or mfc"
                } else {
                    "pid or hinf"
                };
                return reply(request, false, 0, &format!("{name} has no variant `{v}`: {allowed}"));
            }
        };
        if asked.stage == code::STAGE_TORQUE && !self.cascade {
            return reply(
                request,
                false,
                0,
                "the torque stage is bypassed in position-only control: nothing to swap",
            );
        }
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
        let mut child = Supervised::new(
            if asked.stage == code::STAGE_POSITION {
                "position"
            } else {
                "torque"
            },
            &self.dir,
            self.config.clone(),
        );
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
        });
        Ok(())
    }

    /// Names the process that answers `stage` from reading `at_seq` on.
    fn hand_over(&mut self, stage: u32, at_seq: u64, new_pid: u32, variant: u32) -> Result<()> {
        self.handovers.publish(Handover {
            seq: self.handover_seq,
            stage_time_ns: clock::now_ns(),
            at_seq,
            new_pid,
            stage,
            variant,
            reserved: 0,
        })?;
        self.handover_seq += 1;
        Ok(())
    }

    /// The running controller stays in charge; the caller hears why.
    fn fail(&mut self, swap: SwapInProgress, why: &str) -> Result<()> {
        let quality = SwitchQuality {
            missed_cycles: 0,
            command_step: 0.0,
            loop_step_before: 0.0,
            loop_step_after: 0.0,
        };
        self.publish_event(code::EVENT_SWAP_FAILED, &swap, 0, quality)?;
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
        }
        Ok(())
    }

    /// A fault's account, once its process answers again: how long the
    /// detection, the valve's going safe and the restart took.
    fn publish_fault(&mut self, process: &str, fault: Fault, back_at: Option<Instant>) -> Result<()> {
        // The valve's samples up to now, not up to the last tick: a tick
        // that came late (the supervisor shares its CPU with the recorder
        // and everything else) must not hide the valve's going safe.
        self.take_valve_samples()?;
        // The command for reading `seq + 1` was due when reading `seq + 2`
        // came: the fault shows from there; until the guard trips the
        // valve holds its last command.
        let valve_safe = fault
            .last_seq
            .and_then(|seq| self.log.first_fault_after(seq).map(|at| at.saturating_sub(seq + 2)))
            .unwrap_or(u64::MAX);
        self.events.publish(SupervisorEvent {
            seq: self.event_seq,
            stage_time_ns: clock::now_ns(),
            sensor_seq: fault.last_seq.unwrap_or(0),
            valve_safe_after_periods: valve_safe,
            detected_after_ns: fault.silent_for.as_nanos() as u64,
            restarted_after_ns: back_at.map_or(u64::MAX, |at| {
                at.saturating_duration_since(fault.detected_at).as_nanos() as u64
            }),
            kind: fault.kind,
            pid: fault.pid,
            process: fixed_name(process),
            from: fixed_name(fault.variants.map_or("", |v| v.0)),
            to: fixed_name(fault.variants.map_or("", |v| v.1)),
            ..SupervisorEvent::default()
        })?;
        self.event_seq += 1;
        Ok(())
    }

    /// The plant seat changed: fallback or asked for.
    fn publish_plant_event(
        &mut self,
        kind: u32,
        at_seq: u64,
        detected_after: Duration,
        process: &str,
        (from, to): (&str, &str),
        pid: u32,
    ) -> Result<()> {
        self.events.publish(SupervisorEvent {
            seq: self.event_seq,
            stage_time_ns: clock::now_ns(),
            sensor_seq: at_seq,
            valve_safe_after_periods: u64::MAX,
            detected_after_ns: detected_after.as_nanos() as u64,
            restarted_after_ns: u64::MAX,
            kind,
            pid,
            process: fixed_name(process),
            from: fixed_name(from),
            to: fixed_name(to),
            ..SupervisorEvent::default()
        })?;
        self.event_seq += 1;
        Ok(())
    }

    fn publish_event(&mut self, kind: u32, swap: &SwapInProgress, at_seq: u64, quality: SwitchQuality) -> Result<()> {
        self.events.publish(SupervisorEvent {
            seq: self.event_seq,
            stage_time_ns: clock::now_ns(),
            sensor_seq: at_seq,
            missed_cycles: quality.missed_cycles,
            command_step: quality.command_step,
            loop_step_before: quality.loop_step_before,
            loop_step_after: quality.loop_step_after,
            kind,
            pid: swap.child.pid().unwrap_or(0),
            process: fixed_name(code::stage_name(swap.stage)),
            from: fixed_name(swap.from),
            to: fixed_name(swap.to),
            ..SupervisorEvent::default()
        })?;
        self.event_seq += 1;
        Ok(())
    }
}

fn reply(
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
