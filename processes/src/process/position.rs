//! The outer loop and the reference trajectory, on each friction sample.
//! Started with `--standby`, it tracks the running outer loop until a
//! handover puts it in charge (hot swap).

use crate::handover::{Duty, HandoverInbox, Role, Tracker};
use crate::{estimate_of, time_of};
use anyhow::{bail, Result};
use hydractl_bus::{clock, run_single, Inlet, Outlet, Reader};
use hydractl_config::{PositionVariant, Structure};
use hydractl_samples::{code, service, FrictionSample, PositionSample, SensorSample};
use hydractl_stages::{FrictionOutput, PositionStage};

pub fn run() -> Result<()> {
    let started = crate::start("position")?;
    let (bus, config) = (&started.bus, &started.config);
    let variant = match started.args.variant.as_deref() {
        None => config.control.outer().variant,
        Some("pid") => PositionVariant::Pid,
        Some("mfc") => PositionVariant::Mfc,
        Some(other) => bail!("position: no variant `{other}`; the outer loop is `pid` or `mfc`"),
    };
    let mut stage = PositionStage::with_variant(config, variant)?;
    let sensor: Reader<SensorSample> = Reader::open(bus, service::SENSOR, 4)?;
    let friction: Inlet<FrictionSample> = Inlet::open(bus, service::FRICTION, 4)?;
    let running: Reader<PositionSample> = Reader::open(bus, service::POSITION, 4)?;
    let mut inbox = HandoverInbox::open(bus, code::STAGE_POSITION)?;
    let standby_out: Outlet<PositionSample> = Outlet::open(bus, service::POSITION_STANDBY)?;
    // Its output last: a fresh plant starts once every stage publishes,
    // and this one must by then be ready for the first reading.
    let out: Outlet<PositionSample> = Outlet::open(bus, service::POSITION)?;
    let mut role = Role::new(started.args.standby);
    let structure = match stage.structure() {
        Structure::Position => code::STRUCTURE_POSITION,
        Structure::Cascade => code::STRUCTURE_CASCADE,
    };
    let variant = match stage.variant() {
        PositionVariant::Pid => code::VARIANT_PID,
        PositionVariant::Mfc => code::VARIANT_MFC,
    };
    let mut tracker = Tracker::default();
    let mut latest_sensor = SensorSample::default();
    let mut failure = None;
    started.enter_realtime();
    run_single(friction.input(), &started.bus, || {
        hydractl_bus::guarded(&mut failure, || {
            if let Some(s) = sensor.latest()? {
                latest_sensor = s;
            }
            let Some(f) = friction.latest()? else { return Ok(()) };
            started.injected.at_reading(f.sensor_seq);
            let duty = role.duty(&mut inbox, f.sensor_seq)?;
            let newest_running = |r: Option<PositionSample>| r.map(|r| (r.sensor_seq, r.output));
            if duty == Duty::Track {
                if let Some((output, (time, estimate, friction))) = tracker.matched(newest_running(running.latest()?)) {
                    stage.track(output, time, &estimate, friction);
                }
            }
            let estimate = estimate_of(&latest_sensor);
            let time = time_of(f.sensor_seq, config);
            let friction = FrictionOutput {
                compensation: f.compensation,
                load_feedforward: f.load_feedforward,
            };
            let output = stage.process(time, &estimate, friction);
            let sample = PositionSample {
                sensor_seq: f.sensor_seq,
                sensor_time_ns: f.sensor_time_ns,
                stage_time_ns: clock::now_ns(),
                reference_angle: output.reference.angle,
                reference_velocity: output.reference.velocity,
                reference_acceleration: output.reference.acceleration,
                angle: latest_sensor.angle,
                output: output.output,
                structure,
                variant,
            };
            match duty {
                Duty::Publish => out.publish(sample)?,
                Duty::Track => {
                    standby_out.publish(sample)?;
                    tracker.processed(f.sensor_seq, (time, estimate, friction));
                    if let Some((output, (time, estimate, friction))) =
                        tracker.matched(newest_running(running.latest()?))
                    {
                        stage.track(output, time, &estimate, friction);
                    }
                }
                Duty::Silent => {}
            }
            Ok(())
        })
    })?;
    failure.map_or(Ok(()), Err)
}
