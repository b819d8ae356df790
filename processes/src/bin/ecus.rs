//! The machine's CAN nodes on the virtual bus: the valve (CiA 408), the
//! angle encoder (CiA 406) and the two pressure transducers (CiA 404), the
//! simulated ECUs of `hydractl-can`, all on one rotator: the config's
//! `[machine]` (its own parameters and effects) when it has one, the
//! model's otherwise. The rotator runs in real time: before every frame and
//! every millisecond it is integrated up to now with the spool command the
//! valve's electronics held since the last event. The sensors sample the
//! state at the SYNC (noise and quantization their own); the valve follows
//! its set point only when Active and falls to hold when it stops coming.
//! `[machine.silent_node]` and `[machine.stuck_spool]` make one misbehave.

use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use hydractl_bus::{clock, run_until};
use hydractl_can::canopen::is_sync;
use hydractl_can::ecu::{Outbox, SensorEcu, ValveEcu};
use hydractl_can::profile::Transport;
use hydractl_can::Frame;
use hydractl_canio::{CanPort, VirtualCanPort};
use hydractl_plant::Drift;
use hydractl_sim::build_plant;

/// The ECUs' own clock: heartbeats, the valve's RPDO timeout, and the
/// physics between frames.
const TICK: Duration = Duration::from_millis(1);
/// A stalled process does not integrate a second of physics at once: the
/// machine pauses with it.
const MAX_CATCH_UP_NS: u64 = 100_000_000;

fn main() -> Result<()> {
    let started = hydractl_processes::start("ecus")?;
    let can = started
        .config
        .can
        .clone()
        .context("ecus: the config has no [can] table")?;
    if can.transport != Transport::Virtual {
        bail!(
            "ecus: simulated ECUs live on the virtual bus; `{}` is {:?}, the real machine's",
            can.interface,
            can.transport
        );
    }
    let profile = can.resolve().context("ecus: [can]")?;
    let physics = started
        .config
        .machine_plant()?
        .unwrap_or_else(|| started.config.clone());
    let (mut plant, mut sensors) = build_plant(&physics, &[]).context("ecus: the rotator")?;
    // A wearing machine: its effect changes as the machine stand-in's does.
    let drift = match started.config.machine.as_ref().and_then(|m| m.drift.as_ref()) {
        Some(spec) => Some(Drift::new(plant.effects(), spec).context("ecus: [machine.drift]")?),
        None => None,
    };
    let step_ns = (physics.timing.integration_step() * 1e9).round().max(1.0) as u64;
    let silent = started.config.machine.as_ref().and_then(|m| m.silent_node);
    let stuck_after_ns = started
        .config
        .machine
        .as_ref()
        .and_then(|m| m.stuck_spool)
        .map(|s| (s.after_s * 1e9) as u64);
    let port = VirtualCanPort::open(&started.bus, &profile.interface, &[])?;

    let mut valve = ValveEcu::new(&profile);
    let mut encoder = SensorEcu::encoder(&profile);
    let mut transducers = [
        SensorEcu::transducer(&profile, &profile.pressure[0]),
        SensorEcu::transducer(&profile, &profile.pressure[1]),
    ];
    let started_ns = clock::now_ns();
    let silent_from_ns = silent.map(|s| (s.node, started_ns + (s.after_s * 1e9) as u64));
    let mut integrated_ns = started_ns;
    // The spool's command as its electronics hold it; stuck, where it stuck.
    let mut stuck_at: Option<f64> = None;
    let mut spool_command = |valve: &ValveEcu, now_ns: u64| {
        if stuck_after_ns.is_some_and(|after| now_ns >= started_ns + after) {
            *stuck_at.get_or_insert(valve.spool_command())
        } else {
            valve.spool_command()
        }
    };
    let mut failure = None;
    let next_tick = std::cell::Cell::new(Instant::now());
    // The nodes stand in for a machine's own electronics, which a busy
    // computer cannot slow: they answer at the loop's priority, as the
    // simulated plant does. At normal priority a loaded machine held the
    // SYNC's answers back for whole periods, and the stack saw late
    // sensors that a vehicle would not have.
    started.enter_realtime();
    run_until(
        &[port.input()],
        &started.bus,
        || Some(next_tick.get()),
        |_| {
            hydractl_bus::guarded(&mut failure, || -> Result<()> {
                let send = |node: u8, out: &Outbox, now_ns: u64| -> Result<()> {
                    if silent_from_ns.is_some_and(|(n, from)| n == node && now_ns >= from) {
                        return Ok(());
                    }
                    for f in out.frames() {
                        port.send(f)?;
                    }
                    Ok(())
                };
                while let Some(received) = port.receive()? {
                    let now_ns = clock::now_ns();
                    let command = spool_command(&valve, now_ns);
                    integrate_to(&mut plant, drift.as_ref(), &mut integrated_ns, step_ns, now_ns, command);
                    let frame: Frame = received.frame;
                    if is_sync(&frame, profile.sync_cob_id) {
                        let state = plant.state();
                        let raw = sensors.read(&state);
                        encoder.measure(u64::from(profile.encoder_scale.position(raw.angle)));
                        transducers[0].measure(profile.pressure[0].scale.raw(raw.p_a));
                        transducers[1].measure(profile.pressure[1].scale.raw(raw.p_b));
                        valve.set_actual(state.spool);
                    }
                    let mut out = Outbox::default();
                    valve.on_frame(&frame, now_ns, &mut out);
                    send(profile.valve, &out, now_ns)?;
                    for ecu in std::iter::once(&mut encoder).chain(transducers.iter_mut()) {
                        let mut out = Outbox::default();
                        ecu.on_frame(&frame, &mut out);
                        send(ecu.node(), &out, now_ns)?;
                    }
                }
                let now = Instant::now();
                if now >= next_tick.get() {
                    let now_ns = clock::now_ns();
                    let command = spool_command(&valve, now_ns);
                    integrate_to(&mut plant, drift.as_ref(), &mut integrated_ns, step_ns, now_ns, command);
                    let mut out = Outbox::default();
                    valve.tick(now_ns, &mut out);
                    send(profile.valve, &out, now_ns)?;
                    for ecu in std::iter::once(&mut encoder).chain(transducers.iter_mut()) {
                        let mut out = Outbox::default();
                        ecu.tick(now_ns, &mut out);
                        send(ecu.node(), &out, now_ns)?;
                    }
                    next_tick.set((next_tick.get() + TICK).max(now));
                }
                Ok(())
            })
        },
    )?;
    failure.map_or(Ok(()), Err)
}

/// Integrates the rotator from where it was up to `now_ns` in whole steps,
/// with the command held since then.
fn integrate_to(
    plant: &mut hydractl_plant::Plant,
    drift: Option<&Drift>,
    integrated_ns: &mut u64,
    step_ns: u64,
    now_ns: u64,
    command: f64,
) {
    if now_ns.saturating_sub(*integrated_ns) > MAX_CATCH_UP_NS {
        *integrated_ns = now_ns - MAX_CATCH_UP_NS;
    }
    if let Some(drift) = drift {
        plant.drift_to(drift.effects_at(plant.time()));
    }
    let steps = now_ns.saturating_sub(*integrated_ns) / step_ns;
    plant.advance(command, steps as usize);
    *integrated_ns += steps * step_ns;
}
