//! A rotator simulated apart from the model, to test the model tools on
//! data their own simulator did not make. Written from the papers'
//! equations without the plant crate's code: semi-implicit Euler at
//! 20 kHz instead of RK4, and what the model leaves out of every machine:
//! parameters drawn ±40 % around the model's prior, pressure transducers
//! with their own low-pass and a third to three times the default noise,
//! supply-pressure ripple, friction that grows with the square of the
//! speed besides the viscous part, a P position controller with its own
//! gain and a reference of several sines. On top, hidden effects (none,
//! one, or a few of different kinds), each written here in its own way.

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// An effect hidden in a foreign plant, with its true value.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Hidden {
    /// Spool overlap: no flow while |spool − offset| < width (`offset`, the
    /// valve's null offset, is the command that holds the load still).
    Deadzone { width: f64, offset: f64 },
    /// The spool stops at ±limit.
    Saturation { limit: f64 },
    /// The command reaches the valve this much later, s.
    TimeDelay { seconds: f64 },
    /// Flow gain for a negative spool opening, relative to positive.
    AsymmetricGain { ratio: f64 },
    /// Sliding and breakaway friction, N·m.
    CoulombFriction { sliding: f64, breakaway: f64 },
    /// A load torque amplitude · sin(θ − offset), N·m.
    GravityLoad { amplitude: f64, offset: f64 },
    /// Total play between the actuator and the encoder, rad.
    Backlash { width: f64 },
    /// The encoder's step, rad.
    Quantization { step: f64 },
    /// The valve meters turbulently: each edge's flow grows with the
    /// square root of the pressure across it (the orifice equation), within
    /// 0.6 % of the linear law's at half the supply. No parameter.
    OrificeFlow,
}

impl Hidden {
    /// The catalog's name of the effect.
    pub fn name(&self) -> &'static str {
        match self {
            Self::Deadzone { .. } => "deadzone",
            Self::Saturation { .. } => "saturation",
            Self::TimeDelay { .. } => "time_delay",
            Self::AsymmetricGain { .. } => "asymmetric_gain",
            Self::CoulombFriction { .. } => "coulomb_friction",
            Self::GravityLoad { .. } => "gravity_load",
            Self::Backlash { .. } => "backlash",
            Self::Quantization { .. } => "quantization",
            Self::OrificeFlow => "orifice_flow",
        }
    }

    /// The catalog's key of the main parameter and its true value; `None`
    /// for an effect without a parameter, where naming it is all.
    pub fn main(&self) -> Option<(&'static str, f64)> {
        Some(match *self {
            Self::Deadzone { width, .. } => ("width", width),
            Self::Saturation { limit } => ("limit", limit),
            Self::TimeDelay { seconds } => ("delay_s", seconds),
            Self::AsymmetricGain { ratio } => ("ratio", ratio),
            Self::CoulombFriction { sliding, .. } => ("coulomb", sliding),
            Self::GravityLoad { amplitude, .. } => ("amplitude", amplitude),
            Self::Backlash { width } => ("width", width),
            Self::Quantization { step } => ("step", step),
            Self::OrificeFlow => return None,
        })
    }

    /// Whether `fitted`, the diagnosis's value of the main parameter, lies
    /// within `tolerance` (a share) of the truth; an effect without a
    /// parameter is right when named.
    pub fn within(&self, fitted: Option<f64>, tolerance: f64) -> bool {
        self.main()
            .is_none_or(|(_, truth)| fitted.is_some_and(|f| (f - truth).abs() <= tolerance * truth.abs()))
    }

    /// The effects a bench hides, at the catalog's defaults (the
    /// quantization at a 2°-step encoder).
    pub fn all() -> [Hidden; 9] {
        [
            Self::Deadzone {
                width: 0.1,
                offset: 0.0,
            },
            Self::Saturation { limit: 0.5 },
            Self::TimeDelay { seconds: 0.02 },
            Self::AsymmetricGain { ratio: 0.7 },
            Self::CoulombFriction {
                sliding: 60.0,
                breakaway: 90.0,
            },
            Self::GravityLoad {
                amplitude: 150.0,
                offset: 0.0,
            },
            Self::Backlash { width: 0.02 },
            Self::Quantization {
                step: 2f64.to_radians(),
            },
            Self::OrificeFlow,
        ]
    }
}

/// One foreign plant's data: columns `t`, `u`, `p_a`, `p_b` (bar),
/// `theta`, sampled at 1 kHz.
#[derive(Debug, Clone)]
pub struct ForeignData {
    pub t: Vec<f64>,
    pub u: Vec<f64>,
    pub p_a_bar: Vec<f64>,
    pub p_b_bar: Vec<f64>,
    pub theta: Vec<f64>,
    /// What was drawn, for the bench's table.
    pub description: String,
}

/// Which sensors a foreign plant's machine is given.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Sensors {
    /// Valve command, both chamber pressures, angle.
    Full,
    /// Valve command and angle: a machine without pressure transducers.
    Motion,
    /// A measured torque and the angle: an axis whose torque is sensed.
    Torque,
}

impl Sensors {
    /// The columns a record of these sensors holds, named as the model
    /// tools read them.
    pub fn columns(self) -> &'static [&'static str] {
        match self {
            Self::Full => &["t", "u", "p_a", "p_b", "theta"],
            Self::Motion => &["t", "u", "theta"],
            Self::Torque => &["t", "tau", "theta"],
        }
    }
}

impl ForeignData {
    /// The record a machine with `sensors` keeps of this run, every
    /// `every`-th sample: its [`Sensors::columns`], named and in order.
    pub fn record(&self, sensors: Sensors, every: usize) -> Vec<(&'static str, Vec<f64>)> {
        sensors
            .columns()
            .iter()
            .filter_map(|&name| Some((name, self.column(name)?.into_iter().step_by(every).collect())))
            .collect()
    }

    /// A column by the name the model tools read it by.
    pub fn column(&self, name: &str) -> Option<Vec<f64>> {
        Some(match name {
            "t" => self.t.clone(),
            "u" => self.u.clone(),
            "p_a" => self.p_a_bar.clone(),
            "p_b" => self.p_b_bar.clone(),
            "tau" => self.torque_reading(),
            "theta" => self.theta.clone(),
            _ => return None,
        })
    }

    /// What a torque sensor on the shaft reads, N·m: the transducers'
    /// pressure difference through the plant's displacement, with their
    /// noise and lag, for an axis whose torque is measured.
    pub(crate) fn torque_reading(&self) -> Vec<f64> {
        self.p_a_bar
            .iter()
            .zip(&self.p_b_bar)
            .map(|(a, b)| Prior::DISPLACEMENT * (a - b) * 1e5)
            .collect()
    }
}

/// The model's prior, which the foreign plant's parameters scatter around
/// (the values of `[plant]` in `config/sim.toml`).
struct Prior;

impl Prior {
    const SUPPLY: f64 = 180e5;
    const DISPLACEMENT: f64 = 5.0e-5;
    const VOLUME: f64 = 1.0e-3;
    const BULK: f64 = 7.0e8;
    const LEAKAGE: f64 = 5.0e-13;
    const FLOW_GAIN: f64 = 5.0e-5;
    const FLOW_PRESSURE: f64 = 1.0e-12;
    const VALVE_WN: f64 = 32.0;
    const VALVE_ZETA: f64 = 0.3;
    const INERTIA: f64 = 20.0;
    const VISCOUS: f64 = 17.0;
    const NOISE_PA: f64 = 0.1e5;
    const COUNTS_PER_TURN: f64 = 4000.0;
}

const SAMPLE_S: f64 = 1e-3;

const SUBSTEPS: usize = 50;

/// The orifice equation's √Δp relative to its value at half the data
/// sheet's supply, signed (a reversed drop drives flow back), and smoothed
/// within a bar of zero drop, Δp / (|Δp| + 1 bar)^½, so that its slope
/// stays finite: a law of its own, not the model's.
fn orifice_root(drop: f64) -> f64 {
    const TRANSITION_PA: f64 = 1e5;
    drop / ((drop.abs() + TRANSITION_PA) * 0.5 * Prior::SUPPLY).sqrt()
}

/// The hidden effects' values, each kind at most once.
#[derive(Default)]
struct HiddenSet {
    deadzone: Option<(f64, f64)>,
    saturation: Option<f64>,
    delay_s: Option<f64>,
    asymmetric_gain: Option<f64>,
    coulomb: Option<(f64, f64)>,
    gravity: Option<(f64, f64)>,
    backlash: Option<f64>,
    quantization: Option<f64>,
    orifice_flow: bool,
}

impl HiddenSet {
    /// The effects of `hidden`; of a kind given twice, the last.
    fn of(hidden: &[Hidden]) -> Self {
        let mut set = Self::default();
        for h in hidden {
            match *h {
                Hidden::Deadzone { width, offset } => set.deadzone = Some((width, offset)),
                Hidden::Saturation { limit } => set.saturation = Some(limit),
                Hidden::TimeDelay { seconds } => set.delay_s = Some(seconds),
                Hidden::AsymmetricGain { ratio } => set.asymmetric_gain = Some(ratio),
                Hidden::CoulombFriction { sliding, breakaway } => set.coulomb = Some((sliding, breakaway)),
                Hidden::GravityLoad { amplitude, offset } => set.gravity = Some((amplitude, offset)),
                Hidden::Backlash { width } => set.backlash = Some(width),
                Hidden::Quantization { step } => set.quantization = Some(step),
                Hidden::OrificeFlow => set.orifice_flow = true,
            }
        }
        set
    }
}

/// Simulates one foreign plant for `duration_s`, from `seed`, with the
/// `hidden` effects (none, one, or several of different kinds). The plant
/// drawn depends on the seed alone.
pub fn foreign_plant(seed: u64, hidden: &[Hidden], duration_s: f64) -> ForeignData {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut scatter = |nominal: f64| nominal * rng.random_range(0.6..1.4);
    let bulk = scatter(Prior::BULK);
    let flow_gain = scatter(Prior::FLOW_GAIN);
    let flow_pressure = scatter(Prior::FLOW_PRESSURE);
    let leakage = scatter(Prior::LEAKAGE);
    let valve_wn = scatter(Prior::VALVE_WN);
    let valve_zeta = scatter(Prior::VALVE_ZETA);
    let inertia = scatter(Prior::INERTIA);
    let viscous = scatter(Prior::VISCOUS);
    let noise_scale = (rng.random_range(-1.0..1.0f64) * 3f64.ln()).exp();
    let lag_s = rng.random_range(0.5e-3..3e-3);
    let ripple = rng.random_range(0.01..0.03);
    let ripple_hz = rng.random_range(10.0..30.0);
    // Friction growing with the speed's square: 5 to 15 % of the viscous
    // torque at 1 rad/s.
    let quadratic = viscous * rng.random_range(0.05..0.15);
    let gain = rng.random_range(0.8..1.6);
    let phases: [f64; 3] = [
        rng.random_range(0.0..std::f64::consts::TAU),
        rng.random_range(0.0..std::f64::consts::TAU),
        rng.random_range(0.0..std::f64::consts::TAU),
    ];
    let noise =
        Normal::new(0.0, Prior::NOISE_PA * noise_scale).unwrap_or_else(|_| Normal::new(0.0, 1.0).expect("unit normal"));
    let hidden = HiddenSet::of(hidden);
    let step = hidden
        .quantization
        .unwrap_or(std::f64::consts::TAU / Prior::COUNTS_PER_TURN);
    let delay_samples = hidden
        .delay_s
        .map_or(0, |seconds| (seconds / SAMPLE_S).round() as usize);
    let samples = (duration_s / SAMPLE_S).round() as usize;
    let h = SAMPLE_S / SUBSTEPS as f64;
    let (mut spool, mut spool_rate) = (0.0f64, 0.0f64);
    let (mut p_a, mut p_b) = (0.5 * Prior::SUPPLY, 0.5 * Prior::SUPPLY);
    let (mut angle, mut speed) = (0.0f64, 0.0f64);
    let mut load_angle = 0.0f64;
    let (mut sensed_a, mut sensed_b) = (p_a, p_b);
    let mut delayed = std::collections::VecDeque::from(vec![0.0; delay_samples]);
    let mut data = ForeignData {
        t: Vec::with_capacity(samples),
        u: Vec::with_capacity(samples),
        p_a_bar: Vec::with_capacity(samples),
        p_b_bar: Vec::with_capacity(samples),
        theta: Vec::with_capacity(samples),
        description: format!(
            "β {:.2}, K_q {:.2}, K_c {:.2}, C_l {:.2}, ω_v {:.2}, ζ_v {:.2}, J {:.2}, b {:.2} × prior; noise × {noise_scale:.2}, \
             transducer lag {:.1} ms, ripple {:.1} % at {ripple_hz:.0} Hz, P gain {gain:.2}",
            bulk / Prior::BULK,
            flow_gain / Prior::FLOW_GAIN,
            flow_pressure / Prior::FLOW_PRESSURE,
            leakage / Prior::LEAKAGE,
            valve_wn / Prior::VALVE_WN,
            valve_zeta / Prior::VALVE_ZETA,
            inertia / Prior::INERTIA,
            viscous / Prior::VISCOUS,
            lag_s * 1e3,
            ripple * 100.0,
        ),
    };
    for k in 0..samples {
        let t = k as f64 * SAMPLE_S;
        let encoder = (load_angle / step).floor() * step;
        // Sines, and a square wave whose edges drive the valve to its ends.
        let reference = 0.4 * (0.35 * t + phases[0]).sin()
            + 0.2 * (0.9 * t + phases[1]).sin()
            + 0.1 * (2.3 * t + phases[2]).sin()
            + 0.3 * (std::f64::consts::TAU * t / 7.0 + phases[2]).sin().signum();
        let u = (gain * (reference - encoder)).clamp(-1.0, 1.0);
        data.t.push(t);
        data.u.push(u);
        data.p_a_bar.push((sensed_a + noise.sample(&mut rng)) / 1e5);
        data.p_b_bar.push((sensed_b + noise.sample(&mut rng)) / 1e5);
        data.theta.push(encoder);
        delayed.push_back(u);
        let command = delayed.pop_front().unwrap_or(u);
        for i in 0..SUBSTEPS {
            let time = t + i as f64 * h;
            let supply = Prior::SUPPLY * (1.0 + ripple * (std::f64::consts::TAU * ripple_hz * time).sin());
            // Spool: a second-order servo, stopped at its travel limit.
            let accel = valve_wn * valve_wn * (command - spool) - 2.0 * valve_zeta * valve_wn * spool_rate;
            spool_rate += h * accel;
            spool += h * spool_rate;
            if let Some(limit) = hidden.saturation {
                if spool.abs() > limit {
                    spool = spool.signum() * limit;
                    spool_rate = 0.0;
                }
            }
            let mut opening = spool;
            if let Some((width, offset)) = hidden.deadzone {
                let from_centre = opening - offset;
                opening = from_centre.signum() * (from_centre.abs() - width).max(0.0);
            }
            let mut k_q = flow_gain;
            if let (Some(ratio), true) = (hidden.asymmetric_gain, opening < 0.0) {
                k_q *= ratio;
            }
            // Each metering edge's pressure drop, for the orifice law: supply
            // to A and B to tank when opening positive, the other edges when
            // negative.
            let (drop_a, drop_b) = if opening >= 0.0 {
                (supply - p_a, p_b)
            } else {
                (p_a, supply - p_b)
            };
            let (metered_a, metered_b) = if hidden.orifice_flow {
                (
                    2.0 * k_q * opening * orifice_root(drop_a),
                    2.0 * k_q * opening * orifice_root(drop_b),
                )
            } else {
                (2.0 * k_q * opening, 2.0 * k_q * opening)
            };
            let q_a = metered_a - 2.0 * flow_pressure * (p_a - 0.5 * supply);
            let q_b = metered_b + 2.0 * flow_pressure * (p_b - 0.5 * supply);
            let cross = leakage * (p_a - p_b);
            let stiffness = bulk / Prior::VOLUME;
            p_a += h * stiffness * (q_a - Prior::DISPLACEMENT * speed - cross);
            p_b += h * stiffness * (-q_b + Prior::DISPLACEMENT * speed + cross);
            p_a = p_a.clamp(0.0, supply);
            p_b = p_b.clamp(0.0, supply);
            let mut torque = Prior::DISPLACEMENT * (p_a - p_b) - viscous * speed - quadratic * speed * speed.abs();
            if let Some((amplitude, offset)) = hidden.gravity {
                torque -= amplitude * (angle - offset).sin();
            }
            if let Some((sliding, breakaway)) = hidden.coulomb {
                // Held while the drive stays below breakaway; sliding
                // friction once it moves.
                if speed.abs() < 1e-3 && torque.abs() <= breakaway {
                    speed = 0.0;
                    torque = 0.0;
                } else {
                    let direction = if speed != 0.0 { speed.signum() } else { torque.signum() };
                    torque -= sliding * direction;
                }
            }
            speed += h * torque / inertia;
            angle += h * speed;
            load_angle = match hidden.backlash {
                Some(width) => load_angle.clamp(angle - 0.5 * width, angle + 0.5 * width),
                None => angle,
            };
            // The transducers' own first-order lag.
            let blend = h / (lag_s + h);
            sensed_a += blend * (p_a - sensed_a);
            sensed_b += blend * (p_b - sensed_b);
        }
    }
    data
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_foreign_plant_tracks_its_reference_and_stays_within_its_pressures() {
        for seed in 0..3 {
            let data = foreign_plant(seed, &[], 20.0);
            assert_eq!(data.t.len(), 20_000);
            let moved = data.theta.iter().fold(0.0f64, |m, t| m.max(t.abs()));
            assert!(moved > 0.3 && moved < 2.0, "seed {seed}: {moved} rad");
            assert!(data.p_a_bar.iter().all(|p| p.is_finite() && *p > -5.0 && *p < 200.0));
        }
    }

    #[test]
    fn each_hidden_effect_leaves_its_mark() {
        let clean = foreign_plant(7, &[], 20.0);
        for hidden in Hidden::all() {
            let data = foreign_plant(7, &[hidden], 20.0);
            let differs = data.theta.iter().zip(&clean.theta).any(|(a, b)| (a - b).abs() > 1e-3);
            assert!(differs, "{}", hidden.name());
        }
    }
}
