//! A standby controller that tracks the running one takes over without a
//! bump: the hot swap's algorithm, offline, on the closed loop.

use hydractl_config::{Config, PositionVariant, TorqueVariant};
use hydractl_sim::build_plant;
use hydractl_stages::{ControlStack, FrictionOutput, PositionStage, TorqueStage};

/// The valve command's bump (its second difference, over the range 2; the
/// loop's own motion is not a bump): the largest in the 50 ms around the
/// switch, and in the second before it.
#[derive(Default)]
struct BumpMeter {
    around: f64,
    before: f64,
    last: (f64, f64),
}

impl BumpMeter {
    fn record(&mut self, k: usize, switch_at: usize, command: f64) {
        let bump = (command - 2.0 * self.last.0 + self.last.1).abs() / 2.0;
        self.last = (command, self.last.0);
        if k + 1000 >= switch_at && k + 25 < switch_at {
            self.before = self.before.max(bump);
        }
        if k + 25 >= switch_at && k < switch_at + 25 {
            self.around = self.around.max(bump);
        }
    }
}

/// Runs the cascade with `from` as the outer loop and a standby `variant`
/// tracking it, switches at `switch_s`, and returns the largest bump of the
/// valve command (its second difference, over its range) in the 50 ms
/// around the switch and in the second before it. At the switch, the new
/// loop's torque reference must be the old one's, within 10 N·m.
fn switch_position(from: PositionVariant, variant: PositionVariant, switch_s: f64) -> (f64, f64) {
    let mut config = Config::default_sim().expect("config");
    config.control.cascade.variant = from;
    let (mut plant, mut sensors) = build_plant(&config, &[]).expect("plant");
    let mut stack = ControlStack::new(&config).expect("stack");
    let mut standby = PositionStage::with_variant(&config, variant).expect("standby");
    let period = config.timing.control_period();
    let substeps = config.timing.substeps();
    let switch_at = (switch_s / period).round() as usize;
    let mut meter = BumpMeter::default();
    for k in 0..switch_at + 100 {
        let time = k as f64 * period;
        let raw = sensors.read(&plant.state());
        if k == switch_at {
            let sensor = stack.sensor.clone().process(&raw);
            let old = stack
                .position
                .clone()
                .process(time, &sensor, FrictionOutput::default())
                .output;
            let new = standby.clone().process(time, &sensor, FrictionOutput::default()).output;
            // Within what one encoder count is worth through the MFC's gains.
            assert!(
                (old - new).abs() < 10.0,
                "switch: old output {old:.3} N·m, new {new:.3}"
            );
            std::mem::swap(&mut stack.position, &mut standby);
        }
        let out = stack.step(time, &raw);
        if k < switch_at {
            let sensor = out.sensor;
            standby.process(time, &sensor, out.friction);
            standby.track(out.position.output, time, &sensor, out.friction);
        }
        meter.record(k, switch_at, out.command);
        plant.advance(out.command, substeps);
    }
    (meter.around, meter.before)
}

#[test]
fn a_tracking_standby_takes_over_without_a_bump() {
    use PositionVariant::{Mfc, Pid};
    for (from, to, at) in [(Mfc, Pid, 2.0), (Mfc, Pid, 3.3), (Pid, Mfc, 2.0), (Pid, Mfc, 3.3)] {
        let (around, before) = switch_position(from, to, at);
        let variant = to;
        eprintln!("{variant:?} at {at} s: step {around:.4} around the switch, {before:.4} before");
        // The switch is lost in the loop's own period-to-period variation.
        assert!(
            around <= before,
            "{variant:?} at {at} s: {around} around the switch, {before} before"
        );
    }
}

/// As [`switch_position`], for the inner loop: `from` running, `to` tracking.
fn switch_torque(from: TorqueVariant, to: TorqueVariant, switch_s: f64) -> (f64, f64) {
    let mut config = Config::default_sim().expect("config");
    config.control.torque_variant = from;
    let (mut plant, mut sensors) = build_plant(&config, &[]).expect("plant");
    let mut stack = ControlStack::new(&config).expect("stack");
    let mut standby = TorqueStage::with_variant(&config, to).expect("standby");
    let period = config.timing.control_period();
    let substeps = config.timing.substeps();
    let switch_at = (switch_s / period).round() as usize;
    let mut meter = BumpMeter::default();
    for k in 0..switch_at + 100 {
        let time = k as f64 * period;
        let raw = sensors.read(&plant.state());
        if k == switch_at {
            std::mem::swap(&mut stack.torque, &mut standby);
        }
        // The running inner loop's command this period, as step computes it.
        let mut running = stack.torque.clone();
        let out = stack.step(time, &raw);
        if k < switch_at {
            let running = running.process(&out.position, &out.sensor, out.friction.compensation);
            standby.process(&out.position, &out.sensor, out.friction.compensation);
            standby.track(running, &out.position, &out.sensor, out.friction.compensation);
        }
        meter.record(k, switch_at, out.command);
        plant.advance(out.command, substeps);
    }
    (meter.around, meter.before)
}

#[test]
fn a_tracking_inner_loop_takes_over_without_a_bump() {
    use TorqueVariant::{Hinf, Pid};
    for (from, to, at) in [(Pid, Hinf, 2.0), (Pid, Hinf, 3.3), (Hinf, Pid, 2.0), (Hinf, Pid, 3.3)] {
        let (around, before) = switch_torque(from, to, at);
        // The H∞ loop's own bumps are larger than the PID's (its fast modes
        // on noisy pressure): judge the switch against the rougher of the two.
        let (_, new_in_charge) = switch_torque(to, from, at);
        eprintln!("{from:?} → {to:?} at {at} s: bump {around:.4} around the switch; {before:.4} and {new_in_charge:.4} with either in charge");
        assert!(
            around <= 1.05 * before.max(new_in_charge),
            "{to:?} at {at} s: {around} around the switch, {before} and {new_in_charge} in charge"
        );
    }
}
