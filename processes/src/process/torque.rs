//! The inner torque loop on each position sample (passes the command
//! through in position-only control). Started with `--standby`, it tracks
//! the running inner loop until a handover puts it in charge (hot swap).

use crate::estimate_of;
use crate::handover::{Duty, HandoverInbox, Role, Tracker};
use anyhow::{bail, Result};
use hydractl_bus::{clock, run_single, Inlet, Outlet, Reader};
use hydractl_config::TorqueVariant;
use hydractl_samples::{code, service, FrictionSample, PositionSample, SensorSample, TorqueSample};
use hydractl_stages::{PositionOutput, TorqueStage};

pub fn run() -> Result<()> {
    let started = crate::start("torque")?;
    let bus = &started.bus;
    let variant = match started.args.variant.as_deref() {
        None => started.config.control.torque_variant,
        Some("pid") => TorqueVariant::Pid,
        Some("hinf") => TorqueVariant::Hinf,
        Some(other) => bail!("torque: no variant `{other}`; the inner loop is `pid` or `hinf`"),
    };
    let mut stage = TorqueStage::with_variant(&started.config, variant)?;
    let sensor: Reader<SensorSample> = Reader::open(bus, service::SENSOR, 4)?;
    let friction: Reader<FrictionSample> = Reader::open(bus, service::FRICTION, 4)?;
    let position: Inlet<PositionSample> = Inlet::open(bus, service::POSITION, 4)?;
    let running: Reader<TorqueSample> = Reader::open(bus, service::TORQUE, 4)?;
    let mut inbox = HandoverInbox::open(bus, code::STAGE_TORQUE)?;
    let standby_out: Outlet<TorqueSample> = Outlet::open(bus, service::TORQUE_STANDBY)?;
    // Its output last: a fresh plant starts once every stage publishes,
    // and this one must by then be ready for the first reading.
    let out: Outlet<TorqueSample> = Outlet::open(bus, service::TORQUE)?;
    let mut role = Role::new(started.args.standby);
    let variant = match stage.variant() {
        TorqueVariant::Pid => code::VARIANT_PID,
        TorqueVariant::Hinf => code::VARIANT_HINF,
    };
    let mut tracker = Tracker::default();
    let (mut latest_sensor, mut latest_friction) = (SensorSample::default(), FrictionSample::default());
    let mut failure = None;
    started.enter_realtime();
    run_single(position.input(), &started.bus, || {
        hydractl_bus::guarded(&mut failure, || {
            if let Some(s) = sensor.latest()? {
                latest_sensor = s;
            }
            if let Some(f) = friction.latest()? {
                latest_friction = f;
            }
            let Some(p) = position.latest()? else { return Ok(()) };
            started.injected.at_reading(p.sensor_seq);
            let duty = role.duty(&mut inbox, p.sensor_seq)?;
            let newest_running = |r: Option<TorqueSample>| r.map(|r| (r.sensor_seq, r.command));
            if duty == Duty::Track {
                if let Some((command, (output, estimate, friction))) =
                    tracker.matched(newest_running(running.latest()?))
                {
                    stage.track(command, &output, &estimate, friction);
                }
            }
            let output = PositionOutput {
                reference: hydractl_control::Reference {
                    angle: p.reference_angle,
                    velocity: p.reference_velocity,
                    acceleration: p.reference_acceleration,
                },
                output: p.output,
            };
            let estimate = estimate_of(&latest_sensor);
            let command = stage.process(&output, &estimate, latest_friction.compensation);
            let sample = TorqueSample {
                sensor_seq: p.sensor_seq,
                sensor_time_ns: p.sensor_time_ns,
                stage_time_ns: clock::now_ns(),
                torque_reference: p.output,
                torque: latest_sensor.torque,
                command,
                variant,
                reserved: 0,
            };
            match duty {
                Duty::Publish => out.publish(sample)?,
                Duty::Track => {
                    standby_out.publish(sample)?;
                    tracker.processed(p.sensor_seq, (output, estimate, latest_friction.compensation));
                    if let Some((command, (output, estimate, friction))) =
                        tracker.matched(newest_running(running.latest()?))
                    {
                        stage.track(command, &output, &estimate, friction);
                    }
                }
                Duty::Silent => {}
            }
            Ok(())
        })
    })?;
    failure.map_or(Ok(()), Err)
}
