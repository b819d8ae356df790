//! The watchdog's logic: starts every process of the loop, restarts a
//! crashed, hung or misbehaving one with back-off after cleaning its stale
//! iceoryx2 resources, keeps the plant seat, runs hot swaps, accounts for
//! every fault, publishes the status of all, and stops them in order. The
//! `supervisor` binary wires it to its node and ticks it.

mod child;
mod fallback_watch;
mod faults;
mod heartbeats;
mod recorder;
mod seat;
mod service_manager;
mod status;
mod strangers;
mod swaps;
mod tracking;
mod valve_log;

use hydractl_samples::code::EventKind;
use std::time::{Duration, Instant};

use anyhow::Result;
use hydractl_bus::{clock, Bus, CommandServer, Outlet, RunScope};
use hydractl_config::{Config, PositionVariant, Structure, SupervisorConfig, TorqueVariant};
use hydractl_samples::{
    code, fault, service, source, PlantReading, SupervisorReply, SupervisorRequest, SupervisorStatus,
};

use child::{Supervised, PIPELINE};
use fallback_watch::{judge_fallback, FallbackWatch, StageFallbacks};

use faults::{after_limit_cycle, blamed_for_rejections, cpu_times, is_hung, Comeback, CpuWatch, Fault, Liveness};
use heartbeats::{Heartbeats, OuterLoopWatch};
use recorder::RecorderChild;
use seat::Seat;
use service_manager::ServiceManager;
use status::{status_of, LoopMemory};
use strangers::Strangers;
use swaps::{SwapJudge, Swaps};

/// The supervisor's own ports on the loop's services and its command service.
struct Ports {
    commands: CommandServer<SupervisorRequest, SupervisorReply>,
    heartbeats: Heartbeats,
    status: Outlet<SupervisorStatus>,
}

/// A (re)started process gets this long to open its ports.
const STARTUP_GRACE: Duration = Duration::from_millis(500);

/// The supervisor of one run: its children, and what it has seen of them.
pub struct Supervisor {
    scope: RunScope,
    policy: SupervisorConfig,
    /// The valve's limit-cycle judgement, applied to the outer loop's output.
    limit_cycle: hydractl_control::LimitCycleParams,
    /// The loop's processes in [`PIPELINE`] order; `children[0]` is the
    /// plant in charge.
    children: Vec<Supervised>,
    recorder: Option<RecorderChild>,
    /// The shadow model, when the config names one: off the loop, never
    /// on its path; restarted as any process, never waited for.
    shadow: Option<Supervised>,
    swaps: Swaps,
    seat: Seat,
    /// Opened once the children are started, as the supervisor always has:
    /// the loop's services are then the stages' own.
    ports: Option<Ports>,
    own_pid: u32,
    last_status: Instant,
    status_seq: u64,
    last_reading: Option<PlantReading>,
    /// A fault is published once its process is back (or given up on),
    /// with how long each step took.
    faults: Vec<Option<Fault>>,
    /// Each output's newest answer, by its own timestamp.
    last_answer_ns: Vec<u64>,
    restarting: Vec<bool>,
    position_output_finite: bool,
    /// The newest rejected command already acted on.
    misbehaving_handled: Option<u64>,
    /// Each stage's restart into a fallback variant, watched until judged.
    fallbacks: Vec<StageFallbacks>,
    /// Each loop process's use of its CPU.
    cpu: Vec<CpuWatch>,
    /// The previous round: a round that comes late means the supervisor
    /// itself did not run, and the whole computer stalled.
    last_tick: Option<Instant>,
    strangers: Strangers,
    loop_memory: LoopMemory,
    /// systemd, when a unit started the run: ready, and the watchdog.
    service_manager: ServiceManager,
}

impl Supervisor {
    /// Opens the supervisor's ports and lays out its children (none started
    /// yet). `config_path` is passed on to every child; `record` is where a
    /// recorder writes, when the run records.
    pub fn open(bus: &Bus, config: &Config, args: &crate::ProcessArgs) -> Result<Self> {
        let dir = hydractl_bus::process_dir()?;
        let config_path = args.config.clone();
        let mut children: Vec<Supervised> = PIPELINE
            .iter()
            .map(|(name, _, _)| Supervised::new(name, &dir, config_path.clone()))
            .collect();
        // With a machine, it holds the plant seat and the simulated plant
        // waits as its spare.
        let mut seat = Seat::open(bus, config)?;
        if config.machine.is_some() {
            let machine = Supervised::new("machine", &dir, config_path.clone());
            seat.spare = Some(std::mem::replace(&mut children[0], machine));
            seat.source = source::MACHINE;
        }
        let cascade = config.control.structure == Structure::Cascade;
        children[3].variant = Some(match config.control.outer().variant {
            PositionVariant::Pid => "pid",
            PositionVariant::Mfc => "mfc",
        });
        // In position-only control the torque stage passes the command through.
        children[4].variant = cascade.then_some(match config.control.torque_variant {
            TorqueVariant::Pid => "pid",
            TorqueVariant::Hinf => "hinf",
        });
        let recorder = args.record.out.as_ref().map(|out| RecorderChild {
            child: Supervised::new("recorder", &dir, config_path.clone()),
            split: args.record.split.clone(),
            out: out.clone(),
            ring: args.record.ring.clone(),
        });
        let shadow = config
            .shadow
            .model
            .is_some()
            .then(|| Supervised::new("shadow", &dir, config_path.clone()));
        let count = children.len();
        Ok(Self {
            scope: bus.scope().clone(),
            policy: config.supervisor.clone(),
            limit_cycle: config.control.valve_guard.limit_cycle(),
            children,
            recorder,
            shadow,
            swaps: Swaps::open(
                bus,
                dir,
                config_path,
                cascade,
                Duration::from_secs_f64(config.timing.control_period()),
                SwapJudge {
                    readings: config.timing.periods_in_ms(config.supervisor.swap_judge_ms),
                    factor: config.supervisor.swap_rollback_factor,
                    floor_rad: config.supervisor.swap_rollback_min_rms_rad,
                    fallback_settle_readings: config.timing.periods_in_ms(config.supervisor.fallback_settle_ms),
                },
            )?,
            seat,
            ports: None,
            own_pid: std::process::id(),
            last_status: Instant::now(),
            status_seq: 0,
            last_reading: None,
            faults: vec![None; count],
            last_answer_ns: vec![clock::now_ns(); count],
            restarting: vec![true; count],
            position_output_finite: true,
            misbehaving_handled: None,
            fallbacks: vec![StageFallbacks::default(); count],
            cpu: vec![CpuWatch::default(); count],
            last_tick: None,
            strangers: Strangers::new(),
            loop_memory: LoopMemory::default(),
            service_manager: ServiceManager::from_env(),
        })
    }

    /// Starts the recorder first (so that the loop's first samples are
    /// recorded), then the loop's processes and the spare plant.
    pub fn start(&mut self, bus: &Bus) -> Result<()> {
        if let Some(r) = &mut self.recorder {
            r.start(bus, &self.scope)?;
        }
        // Subscribed before the stages publish: each connects to these as
        // it opens its output, not on its loop.
        self.ports = Some(Ports {
            commands: CommandServer::open(bus, service::SUPERVISOR_COMMAND)?,
            heartbeats: Heartbeats::open(
                bus,
                OuterLoopWatch::new(hydractl_control::LimitCycleDetector::new(self.limit_cycle)?),
            )?,
            status: Outlet::open(bus, service::SUPERVISOR_STATUS)?,
        });
        for child in self.children.iter_mut() {
            child.spawn(&self.scope, &[])?;
        }
        if let Some(spare) = &mut self.seat.spare {
            spare.spawn(&self.scope, &["--standby".to_owned()])?;
        }
        if let Some(shadow) = &mut self.shadow {
            shadow.spawn(&self.scope, &[])?;
        }
        let now = clock::now_ns();
        self.last_answer_ns.iter_mut().for_each(|t| *t = now);
        Ok(())
    }

    /// One round of watching, every few milliseconds: heartbeats, the
    /// machine's loss, misbehaving controllers, crashes and hangs,
    /// restarts, commands, swaps and the status.
    pub fn tick(&mut self, bus: &Bus, now: Instant) -> Result<()> {
        let Self {
            scope,
            policy,
            limit_cycle: _,
            children,
            recorder,
            shadow,
            swaps,
            seat,
            ports,
            own_pid,
            last_status,
            status_seq,
            last_reading,
            faults,
            last_answer_ns,
            restarting,
            position_output_finite,
            misbehaving_handled,
            fallbacks,
            cpu,
            last_tick,
            strangers,
            loop_memory,
            service_manager,
        } = self;
        let Some(Ports {
            commands,
            heartbeats,
            status,
        }) = ports
        else {
            return Ok(());
        };
        let (scope, policy, own_pid) = (&*scope, &*policy, *own_pid);
        let hung_after = Duration::from_millis(policy.hung_after_ms);
        let advanced = heartbeats.advanced(last_reading, position_output_finite)?;
        if let Some(r) = last_reading {
            swaps.note_reading(r);
        }
        // Whether each output had paused, before this round's news, by
        // its own timestamps (a just-restarted process has none yet).
        let now_ns = clock::now_ns();
        let mut paused = [false; PIPELINE.len()];
        for (p, last_ns) in paused.iter_mut().zip(last_answer_ns.iter()) {
            *p = Duration::from_nanos(now_ns.saturating_sub(*last_ns)) >= hung_after / 2;
        }
        for i in 0..children.len() {
            if let Some(answer) = advanced[i] {
                children[i].last_output = now;
                children[i].last_seq = Some(answer.seq);
                last_answer_ns[i] = answer.time_ns;
                // Back after a fault: the fault's account is complete. An
                // answer the killed process published before it died, read
                // only now, is not its successor's (it closed a limit
                // cycle's 500 ms wait as 11 ms, and an 8 s one as 14 ms).
                let from_successor = children[i].answered_by_current(answer.time_ns);
                if let Some(watch) = fallbacks[i].watch.as_mut().filter(|_| from_successor) {
                    watch.answered(answer.seq, swaps.tracking().1);
                }
                if let Some(fault) = faults[i].take_if(|_| from_successor) {
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
        // is restarted, into its fallback variant if the config names one.
        let rejected = swaps.log.rejected(
            fault::NOT_FINITE | fault::OUT_OF_RANGE | fault::LIMIT_CYCLE,
            2 * policy.misbehaving_after_periods,
            *misbehaving_handled,
        );
        if rejected.count >= policy.misbehaving_after_periods {
            *misbehaving_handled = rejected.newest;
            let limit_cycling = rejected.why & fault::LIMIT_CYCLE != 0;
            let i = blamed_for_rejections(
                *position_output_finite,
                limit_cycling && heartbeats.outer_loop().limit_cycling,
                children[4].variant.is_none(),
            );
            let child = &mut children[i];
            if child.is_running() {
                let (kind, what) = if limit_cycling {
                    (EventKind::LimitCycle, "limit-cycling")
                } else {
                    (EventKind::Misbehaving, "garbage")
                };
                let from = child.variant;
                let fallback = fallbacks[i].allowed(
                    policy
                        .fallback_variants
                        .get(child.name)
                        .and_then(|v| code::variant_code(v))
                        .map(code::variant_name),
                );
                let comeback = match (limit_cycling, from) {
                    (true, Some(running)) => {
                        child.limit_cycles += 1;
                        after_limit_cycle(
                            policy.on_limit_cycle,
                            running,
                            fallback,
                            child.limit_cycles,
                            Duration::from_millis(policy.limit_cycle_backoff_ms),
                        )
                    }
                    _ => Comeback::Restart {
                        variant: fallback.or(from).unwrap_or("pid"),
                        after: Duration::ZERO,
                    },
                };
                if let Comeback::Restart { variant, .. } = comeback {
                    child.variant = Some(variant);
                    // Into another variant: judged by the tracking that follows.
                    if let (Some(failed), Some(newest)) = (from.filter(|&f| f != variant), rejected.newest) {
                        let (tracking, judge, _) = swaps.tracking();
                        let fault = (
                            newest.saturating_sub(rejected.count),
                            last_reading.map_or(newest, |r| r.sensor_seq.max(newest)),
                        );
                        fallbacks[i].watch = FallbackWatch::new(failed, variant, fault, tracking, judge, now);
                    }
                }
                faults[i] = Some(Fault {
                    kind,
                    pid: child.pid().unwrap_or(0),
                    detected_at: now,
                    silent_for: Duration::ZERO,
                    last_seq: rejected.newest.map(|s| s.saturating_sub(rejected.count)),
                    variants: from.zip(child.variant),
                    valve_safe_after: None,
                });
                child.kill_hung();
                cleanup_needed = true;
                restarting[i] = match comeback {
                    Comeback::Restart { after, .. } => {
                        let scheduled = child.after_stop(now, policy);
                        child.delay_restart(now + after);
                        scheduled
                    }
                    Comeback::LeaveDown => {
                        child.give_up(format!("its commands {what}; on_limit_cycle = \"stop\""));
                        false
                    }
                };
                tracing::warn!(
                    "the valve rejected {} commands in {} readings as {what}: {} misbehaves; {}",
                    rejected.count,
                    2 * policy.misbehaving_after_periods,
                    child.name,
                    match comeback {
                        Comeback::Restart { variant, after } if after.is_zero() => format!("restarting it ({variant})"),
                        Comeback::Restart { variant, after } => {
                            format!("restarting it ({variant}) in {} ms", after.as_millis())
                        }
                        Comeback::LeaveDown => "leaving it down, the valve neutral".to_owned(),
                    }
                );
                if i == 3 {
                    heartbeats.outer_loop().reset();
                }
            }
        }
        for (stage, child) in fallbacks.iter_mut().zip(children.iter_mut()) {
            let at_seq = last_reading.map_or(0, |r| r.sensor_seq);
            cleanup_needed |= judge_fallback(stage, child, swaps, policy, at_seq, now)?;
        }
        // A round this late means the supervisor did not run either: the
        // whole computer stalled, and a process quiet through it is not hung.
        let computer_stalled = last_tick.is_some_and(|t| now.saturating_duration_since(t) >= hung_after / 2);
        *last_tick = Some(now);
        // A process over its CPU share for long spins: it starves every
        // process beside it, which must not be blamed for their silence.
        let spinning_after = Duration::from_millis(policy.spinning_after_ms);
        let mut spinner_found = false;
        for i in 0..children.len() {
            let child = &mut children[i];
            let Some(pid) = child.pid() else {
                cpu[i] = CpuWatch::default();
                continue;
            };
            cpu[i].update(pid, now, cpu_times(pid), policy.spinning_cpu_share);
            if child.uptime(now) > STARTUP_GRACE && cpu[i].busy_for >= spinning_after {
                let busy_for = cpu[i].busy_for;
                faults[i] = Some(Fault {
                    kind: EventKind::Spin,
                    pid,
                    detected_at: now,
                    silent_for: Duration::from_nanos(clock::now_ns().saturating_sub(last_answer_ns[i])),
                    last_seq: child.last_seq,
                    variants: None,
                    valve_safe_after: None,
                });
                child.kill_hung();
                cleanup_needed = true;
                spinner_found = true;
                tracing::error!(
                    "{} (pid {pid}) spins: more than {:.0} % of its CPU for {} ms; killed",
                    child.name,
                    policy.spinning_cpu_share * 100.0,
                    busy_for.as_millis()
                );
                restarting[i] = child.after_stop(now, policy);
            }
        }
        if computer_stalled || spinner_found {
            // Quiet is counted from now: the processes could not run.
            for child in children.iter_mut() {
                child.input_resumed = now;
            }
        }
        for i in 0..children.len() {
            // The input flows when its producer's outputs do, by their own
            // timestamps: a producer just restarted has none yet.
            let input_flowing =
                i == 0 || Duration::from_nanos(clock::now_ns().saturating_sub(last_answer_ns[i - 1])) < hung_after / 2;
            let child = &mut children[i];
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
                valve_safe_after: None,
            };
            if child.reap() {
                tracing::error!(
                    child = child.name,
                    child_pid = pid,
                    seq = last_seq.unwrap_or(0),
                    "{} (pid {pid}) exited after reading {}",
                    child.name,
                    last_seq.unwrap_or(0)
                );
                faults[i] = Some(fault(EventKind::Crash));
                cleanup_needed = true;
                restarting[i] = child.after_stop(now, policy);
            } else if child.is_running()
                // Kept off its CPU by something else: starved, not hung.
                && cpu[i].starved_for < hung_after / 2
                && is_hung(
                    Liveness {
                        uptime: child.uptime(now),
                        input_flowing,
                        quiet_for: now.saturating_duration_since(child.last_output.max(child.input_resumed)),
                    },
                    STARTUP_GRACE,
                    hung_after,
                )
            {
                tracing::error!(
                    child = child.name,
                    child_pid = pid,
                    seq = last_seq.unwrap_or(0),
                    "{} (pid {pid}) hung: no output for {} ms while its input flowed; killed",
                    child.name,
                    silent_for.as_millis()
                );
                faults[i] = Some(fault(EventKind::Hang));
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
                    tracing::error!("{} is left down: {why}", children[i].name);
                    swaps.publish_fault(children[i].name, fault, None)?;
                }
            }
        }
        if let Some(r) = recorder.as_mut() {
            if r.child.reap() {
                cleanup_needed = true;
                if !r.child.after_stop(now, policy) {
                    let why = r.child.given_up.clone().unwrap_or_default();
                    tracing::error!("the recorder is left down: {why}");
                }
            }
        }
        if let Some(shadow) = shadow.as_mut() {
            if shadow.reap() {
                cleanup_needed = true;
                if !shadow.after_stop(now, policy) {
                    let why = shadow.given_up.clone().unwrap_or_default();
                    tracing::error!("the shadow model is left down: {why}");
                }
            }
        }
        if cleanup_needed {
            scope.remove_dead_nodes()?;
        }
        // How soon the valve was safe, as soon as its samples say.
        for fault in faults.iter_mut().flatten() {
            if fault.valve_safe_after.is_none() {
                fault.valve_safe_after = swaps.valve_safe_after(fault);
            }
        }
        if let Some(r) = recorder.as_mut() {
            if r.child.restart_due(now) {
                r.restart(scope)?;
            }
        }
        if let Some(shadow) = shadow.as_mut() {
            if shadow.restart_due(now) {
                shadow.spawn(scope, &[])?;
                shadow.restarts += 1;
            }
        }
        for child in children.iter_mut() {
            if child.restart_due(now) {
                // A new plant goes on from the loop's last reading.
                let args: Vec<String> = match (child.name, *last_reading) {
                    ("plant", Some(r)) => vec![
                        "--resume".into(),
                        crate::Resume {
                            seq: r.sensor_seq,
                            angle: r.true_angle,
                            p_a: r.p_a,
                            p_b: r.p_b,
                            velocity: heartbeats.velocity,
                        }
                        .to_arg(),
                    ],
                    _ => Vec::new(),
                };
                child.spawn(scope, &args)?;
                child.restarts += 1;
                if child.name == "position" {
                    heartbeats.outer_loop().reset();
                }
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
        let loop_answers = service_manager.awaits_ready() && swaps.log.answered_any();
        service_manager.tick(now, loop_answers);
        // Publishers that are none of the run's processes.
        let mut ours: Vec<u32> = children
            .iter()
            .chain(seat.spare.iter())
            .filter_map(Supervised::pid)
            .collect();
        ours.extend(recorder.as_ref().and_then(|r| r.child.pid()));
        ours.extend(shadow.as_ref().and_then(Supervised::pid));
        ours.extend(swaps.standby_pid());
        ours.push(own_pid);
        for (pid, name) in strangers.look(bus, now, &ours) {
            tracing::warn!("process {pid} publishes on {name} and is not one of the run's: a stranger");
            swaps.publish_plant_event(
                EventKind::Stranger,
                last_reading.map_or(0, |r| r.sensor_seq),
                Duration::ZERO,
                name.trim_start_matches("hydractl/"),
                ("", ""),
                pid,
            )?;
        }
        if now.saturating_duration_since(*last_status) >= Duration::from_millis(100) {
            *last_status = now;
            let recorder = recorder.as_ref().map(|r| &r.child);
            status.publish(status_of(
                *status_seq,
                children,
                seat,
                recorder.into_iter().chain(shadow.as_ref()),
                own_pid,
                now,
                hung_after,
                loop_memory,
            ))?;
            *status_seq += 1;
        }
        Ok(())
    }

    /// Stops the loop, then the recorder, which drains what the loop last
    /// published and finishes its file; then cleans what is left of the run.
    pub fn stop(self, bus: Bus) -> Result<()> {
        let Self {
            scope,
            policy,
            mut children,
            mut recorder,
            mut shadow,
            swaps,
            mut seat,
            ports,
            strangers,
            ..
        } = self;
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
        // Before the recorder, which records its last window.
        if let Some(shadow) = &mut shadow {
            shadow.request_stop();
            shadow.finish_stop(Instant::now() + Duration::from_secs(2));
        }
        if let Some(r) = &mut recorder {
            r.child.request_stop();
            // Finishing a file (its last chunk, summary and indexes) takes
            // longer than a control process's stop.
            r.child.finish_stop(Instant::now() + Duration::from_secs(10));
        }
        // Ports before their node: a port keeps its node alive.
        drop((swaps, seat, ports, strangers));
        drop(bus);
        Ok(scope.clean_stale()?)
    }
}
