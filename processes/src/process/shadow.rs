//! The shadow model beside the machine (`[shadow] model`): compares the
//! model with the live samples over a sliding window and publishes the fit
//! on `hydractl/shadow`, and a drift from the model, once detected and once
//! named, on `hydractl/shadow/drift`. Off the loop's CPU, never on its path:
//! it only reads the loop's services.

use std::time::Duration;

use crate::shadow::ShadowWatch;
use anyhow::Result;
use hydractl_bus::{clock, run_loop, Outlet, Reader};
use hydractl_samples::{service, source, ModelDrift, PlantReading, ShadowSample, ValveSample};

/// How often the readings are drained: well within the 256 samples a
/// subscriber keeps at 1 kHz.
const DRAIN_EVERY: Duration = Duration::from_millis(50);

pub fn run() -> Result<()> {
    let started = crate::start("shadow")?;
    let bus = &started.bus;
    let watched = if started.config.machine.is_some() {
        source::MACHINE
    } else {
        source::SIMULATION
    };
    let mut watch = ShadowWatch::open(&started.config.shadow, started.config.timing.control_period(), watched)?;
    let readings: Reader<PlantReading> = Reader::open(bus, service::PLANT_READING, 256)?;
    let valve: Reader<ValveSample> = Reader::open(bus, service::VALVE, 256)?;
    let fit: Outlet<ShadowSample> = Outlet::open(bus, service::SHADOW)?;
    let drifts: Outlet<ModelDrift> = Outlet::open(bus, service::SHADOW_DRIFT)?;
    let mut last = None;
    let (mut windows, mut drift_messages) = (0u64, 0u64);
    let mut failure = None;
    run_loop(&[], Some(DRAIN_EVERY), bus, |_| {
        hydractl_bus::guarded(&mut failure, || -> Result<()> {
            while let Some(r) = readings.next()? {
                last = Some(r);
                watch.rows().reading(r);
            }
            while let Some(v) = valve.next()? {
                watch.rows().valve(v);
            }
            let out = watch.step(last.as_ref(), clock::now_ns())?;
            if let Some(sample) = out.sample {
                fit.publish(ShadowSample { seq: windows, ..sample })?;
                windows += 1;
            }
            for event in out.drift {
                drifts.publish(ModelDrift {
                    seq: drift_messages,
                    ..event
                })?;
                drift_messages += 1;
            }
            Ok(())
        })
    })?;
    failure.map_or(Ok(()), Err)
}
