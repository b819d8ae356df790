//! The watchdog: starts every process of the loop, restarts a crashed or
//! hung one with back-off after cleaning its stale iceoryx2 resources,
//! publishes the status of all, and on SIGTERM or SIGINT stops them and
//! removes every file of the run.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{bail, Result};
use hydractl_bus::{clock, run_loop, Bus, Outlet, Reader, RunScope};
use hydractl_processes::supervision::{Supervised, PIPELINE};
use hydractl_processes::RecordArgs;
use hydractl_samples::{
    fixed_name, service, FrictionSample, PlantReading, PositionSample, ProcessStatus, RecorderStatus, SensorSample,
    SupervisorStatus, TorqueSample, ValveSample, MAX_PROCESSES,
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

    /// Which of the pipeline's outputs advanced since the last call, in
    /// [`PIPELINE`] order; keeps the plant's last reading for a restart.
    fn advanced(&self, last_reading: &mut Option<PlantReading>) -> Result<[bool; 6]> {
        let reading = self.plant.latest()?;
        if reading.is_some() {
            *last_reading = reading;
        }
        Ok([
            reading.is_some(),
            self.sensor.latest()?.is_some(),
            self.friction.latest()?.is_some(),
            self.position.latest()?.is_some(),
            self.torque.latest()?.is_some(),
            self.valve.latest()?.is_some(),
        ])
    }
}

fn main() -> Result<()> {
    let started = hydractl_processes::start("supervisor")?;
    let scope = started.bus.scope().clone();
    let policy = started.config.supervisor.clone();
    // Over what a crashed run left: its dead nodes (its files, when nothing
    // of it was alive, `hydractl run` removed before starting us).
    scope.remove_dead_nodes()?;
    let dir = hydractl_bus::binary_dir()?;
    let mut children: Vec<Supervised> = PIPELINE
        .iter()
        .map(|(name, _, _)| Supervised::new(name, &dir, started.args.config.clone()))
        .collect();
    let mut recorder = started.args.record.out.as_ref().map(|out| RecorderChild {
        child: Supervised::new("recorder", &dir, started.args.config.clone()),
        args: started.args.record.clone(),
        out: out.clone(),
    });
    let outcome = match &mut recorder {
        Some(r) => r.start(&started.bus, &scope),
        None => Ok(()),
    }
    .and_then(|()| supervise(&started.bus, &scope, &policy, &mut children, &mut recorder));

    // Stop the loop, then the recorder, which drains what the loop last
    // published and finishes its file; then clean what is left.
    let deadline = Instant::now() + Duration::from_millis(policy.stop_timeout_ms);
    for child in children.iter().rev() {
        child.request_stop();
    }
    for child in children.iter_mut().rev() {
        child.finish_stop(deadline);
    }
    if let Some(r) = &mut recorder {
        r.child.request_stop();
        // Finishing a file (its last chunk, summary and indexes) takes longer
        // than a control process's stop.
        r.child.finish_stop(Instant::now() + Duration::from_secs(10));
    }
    drop(started.bus);
    // Clean up whatever the outcome; report the outcome's error first.
    let cleaned = scope.clean_stale();
    outcome.and(cleaned.map_err(Into::into))
}

/// The recorder, when the run records: started before the loop, so that
/// the loop's first samples are recorded, and stopped after it.
struct RecorderChild {
    child: Supervised,
    args: RecordArgs,
    out: PathBuf,
}

impl RecorderChild {
    /// Starts the recorder and waits until it is subscribed (its first
    /// status); a recorder that dies first (an unwritable file, say) fails
    /// the run, having said why on stderr.
    fn start(&mut self, bus: &Bus, scope: &RunScope) -> Result<()> {
        let ready: Reader<RecorderStatus> = Reader::open(bus, service::RECORDER_STATUS, 4)?;
        self.child.spawn(scope, &self.args.to_args(&self.out))?;
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
        self.child.spawn(scope, &self.args.to_args(&out))?;
        self.child.restarts = n;
        Ok(())
    }
}

fn supervise(
    bus: &Bus,
    scope: &RunScope,
    policy: &hydractl_sim::SupervisorConfig,
    children: &mut [Supervised],
    recorder: &mut Option<RecorderChild>,
) -> Result<()> {
    for child in children.iter_mut() {
        child.spawn(scope, &[])?;
    }
    let mut last_reading: Option<PlantReading> = None;
    let heartbeats = Heartbeats::open(bus)?;
    let status: Outlet<SupervisorStatus> = Outlet::open(bus, service::SUPERVISOR_STATUS)?;
    let hung_after = Duration::from_millis(policy.hung_after_ms);
    // A (re)started process gets this long to open its ports.
    let startup_grace = Duration::from_millis(500);
    let own_pid = std::process::id();
    let mut last_status = Instant::now();
    let mut status_seq = 0u64;
    let mut failure = None;
    run_loop(&[], Some(Duration::from_millis(5)), |_| {
        hydractl_bus::guarded(&mut failure, || -> Result<()> {
            let now = Instant::now();
            let advanced = heartbeats.advanced(&mut last_reading)?;
            // Whether each output had paused, before this round's news.
            let mut paused = [false; PIPELINE.len()];
            for (p, c) in paused.iter_mut().zip(children.iter()) {
                *p = now.saturating_duration_since(c.last_output) >= hung_after / 2;
            }
            for i in 0..children.len() {
                if advanced[i] {
                    children[i].last_output = now;
                }
                // Input back after a pause: measure a hang from now on.
                if i > 0 && advanced[i - 1] && paused[i - 1] {
                    children[i].input_resumed = now;
                }
            }
            let mut cleanup_needed = false;
            for i in 0..children.len() {
                // Hung: running past its grace, its input flowing (the plant
                // paces itself), and no output for `hung_after`.
                let input_flowing =
                    i == 0 || now.saturating_duration_since(children[i - 1].last_output) < hung_after / 2;
                let child = &mut children[i];
                let quiet_since = child.last_output.max(child.input_resumed);
                if child.reap() {
                    cleanup_needed = true;
                    child.schedule_restart(now, policy);
                } else if child.is_running()
                    && child.uptime(now) > startup_grace
                    && input_flowing
                    && now.saturating_duration_since(quiet_since) > hung_after
                {
                    child.kill_hung();
                    cleanup_needed = true;
                    child.schedule_restart(now, policy);
                }
            }
            if let Some(r) = recorder.as_mut() {
                if r.child.reap() {
                    cleanup_needed = true;
                    r.child.schedule_restart(now, policy);
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
            if now.saturating_duration_since(last_status) >= Duration::from_millis(100) {
                last_status = now;
                let recorder = recorder.as_ref().map(|r| &r.child);
                status.publish(status_of(status_seq, children, recorder, own_pid, now, hung_after))?;
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
    recorder: Option<&Supervised>,
    own_pid: u32,
    now: Instant,
    hung_after: Duration,
) -> SupervisorStatus {
    let mut status = SupervisorStatus {
        seq,
        stage_time_ns: clock::now_ns(),
        ..SupervisorStatus::default()
    };
    let entries = children.iter().map(|c| ProcessStatus {
        name: fixed_name(c.name),
        variant: [0; 16],
        pid: c.pid().unwrap_or(0),
        restarts: c.restarts,
        healthy: u32::from(c.is_running() && now.saturating_duration_since(c.last_output) <= hung_after),
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
        .zip(entries.chain(recorder).chain(std::iter::once(supervisor)))
    {
        *slot = entry;
        count += 1;
    }
    status.process_count = count.min(MAX_PROCESSES) as u32;
    status
}
