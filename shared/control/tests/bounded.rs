//! No NaN or infinity out of any controller for any bounded input.

use hydractl_control::{
    FrictionCompensator, FrictionCompensatorParams, HInfinity, HInfinityParams, LoadFeedforward, LoadModel, Mfc,
    MfcParams, Pid, PidParams, StaticMap, ValveShaper, ValveShaperParams, VelocityEstimator, VelocityEstimatorParams,
    VelocityMethod,
};
use proptest::prelude::*;

fn pid_params() -> PidParams {
    PidParams {
        kp: 3.0,
        ki: 2.0,
        kd: 0.1,
        output_min: -1.0,
        output_max: 1.0,
        ..PidParams::default()
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]
    #[test]
    fn controllers_stay_finite_and_in_their_limits(inputs in proptest::collection::vec((-1e3f64..1e3, -1e3f64..1e3), 1..400)) {
        let ts = 0.001;
        let mut pid = Pid::new(pid_params(), ts).expect("valid");
        let mut mfc = Mfc::new(MfcParams {
            j_hat: 0.025, b_hat: 0.5, pid_a: pid_params(), pid_b: PidParams { kp: 20.0, kd: 1.0, ..PidParams::default() },
            output_min: -1.0, output_max: 1.0,
        }, ts).expect("valid");
        let mut hinf = HInfinity::new(HInfinityParams::default(), ts).expect("valid");
        let mut friction = FrictionCompensator::new(FrictionCompensatorParams {
            alpha_width: 0.1, mu: 0.001, map: StaticMap::linear(0.5, 3.0),
            load: LoadFeedforward { coulomb: 40.0, gravity_amplitude: 200.0, ..LoadFeedforward::default() },
        }).expect("valid");
        let mut valve = ValveShaper::new(ValveShaperParams { deadzone_width: 0.1, ..ValveShaperParams::default() }, ts).expect("valid");
        let load = LoadModel { inertia: 20.0, viscous_friction: 17.0 };
        let mut velocity = VelocityEstimator::new(VelocityEstimatorParams::default(), load, ts).expect("valid");
        let observer = VelocityEstimatorParams { method: VelocityMethod::Observer, ..VelocityEstimatorParams::default() };
        let mut observed = VelocityEstimator::new(observer, load, ts).expect("valid");
        for (a, b) in inputs {
            let u = pid.update(a, b * 1e-3);
            prop_assert!(u.is_finite() && (-1.0..=1.0).contains(&u));
            let u = mfc.update(a, b, Some(a - b), 0.0);
            prop_assert!(u.is_finite() && (-1.0..=1.0).contains(&u));
            let u = hinf.update(a);
            prop_assert!(u.is_finite() && (-1.0..=1.0).contains(&u));
            let f = friction.update(a, b, a - b);
            prop_assert!(f.is_finite() && f.abs() <= 1.5);
            let load = friction.load_feedforward(a);
            prop_assert!(load.is_finite() && load.abs() <= 240.0);
            let v = valve.update(a);
            prop_assert!(v.is_finite() && (-1.0..=1.0).contains(&v));
            prop_assert!(velocity.update(a, b).is_finite());
            prop_assert!(observed.update(a, b * 1e3).is_finite());
        }
    }
}
