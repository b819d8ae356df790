use hydractl_control::{PAPER_HINF_DEN, PAPER_HINF_NUM};
use hydractl_lti::TransferFunction;

use super::*;

fn tf(num: &[f64], den: &[f64]) -> TransferFunction {
    TransferFunction::new(num.to_vec(), den.to_vec()).expect("tf")
}

#[test]
fn an_integrator_is_robust_to_one_over_root_two_of_its_coprime_factors() {
    // The closed form for 1/s: X = Z = 1, γ_min = √(1 + 1).
    let design = glover_mcfarlane(&tf(&[1.0], &[1.0, 0.0]).to_state_space(), 1.1).expect("design");
    assert!((design.gamma_min - 2f64.sqrt()).abs() < 1e-9, "{}", design.gamma_min);
}

/// MathWorks' `ncfsyn` example: a lightly damped P = 16/(s² + 0.16 s + 16)
/// shaped by a PI, 1 + 0.8/s, and a roll-off at 20 rad/s; it reports
/// γ = 1.9903 for a controller a hair above the optimum.
#[test]
fn the_published_ncfsyn_example_gives_its_gamma() {
    let plant = tf(&[16.0], &[1.0, 0.16, 16.0]);
    let weight = tf(&[1.0, 0.8], &[1.0 / 20.0, 1.0, 0.0]);
    let shaped = weight.to_state_space().series(&plant.to_state_space()).expect("series");
    let design = glover_mcfarlane(&shaped, 1.1).expect("design");
    assert!(
        design.gamma_min <= 1.9903 && design.gamma_min > 1.9903 * 0.998,
        "γ_min {}",
        design.gamma_min
    );
    // The controller holds its promise: stable, and the coprime-factor
    // norm at most γ (and, at the optimum's 1.1 times, above γ_min).
    let margins = loop_margins(&shaped, &design.controller).expect("margins");
    assert!(margins.closed_loop_stable, "{margins:?}");
    let achieved = coprime_robustness(&shaped, &design.controller);
    assert!(
        achieved <= design.gamma * 1.001 && achieved >= design.gamma_min,
        "{achieved} vs γ {}",
        design.gamma
    );
}

/// The crane paper's force controller (its eq. 8) for its identified plant
/// (eq. 7) with the target loop 1/(s/3 + 1): `loopsyn`'s weight `L_d / P`
/// and a controller close to the optimum give it back within 0.7 dB and 1°
/// over three decades (the paper's loop gain is 7 % above the optimum's).
#[test]
fn the_crane_papers_controller_is_reproduced_from_its_plant_and_target() {
    let plant = tf(
        &[2.123e5, 4.253e7, 4.579e8, 6.197e8],
        &[1.0, 15.68, 647.2, 8636.0, 2.353e4],
    );
    let target = tf(&[1.0], &[1.0 / 3.0, 1.0]);
    let weight = target_loop_weight(&plant, &target).expect("weight");
    let design = design(&plant, &weight, 1.0001).expect("design");
    let paper = tf(&PAPER_HINF_NUM, &PAPER_HINF_DEN);
    for omega in [0.1, 0.3, 1.0, 3.0, 10.0, 30.0, 100.0] {
        let ours = design.controller.frequency_response(omega);
        let theirs = paper.frequency_response(omega);
        let db = 20.0 * (ours.norm() / theirs.norm()).log10();
        let degrees = (ours / theirs).arg().to_degrees();
        assert!(
            db.abs() < 0.7 && degrees.abs() < 1.0,
            "at {omega} rad/s: {db:+.2} dB, {degrees:+.1}°"
        );
    }
    assert!(design.margins.closed_loop_stable);
}

/// The torque loop's plant of the simulated rotator (`ident hinf` fits it,
/// coefficients from 1 to 10⁷): every crossover a user might ask for gives
/// a controller that holds the model, its γ rising with the crossover.
#[test]
fn a_hydraulic_plant_is_designed_for_across_its_crossovers() {
    let plant = tf(&[7.0552e6, 8.7560e6], &[1.0, 22.922, 1226.6, 7903.5, 1725.4]);
    let mut previous_gamma = 1.0;
    for crossover in [10.0, 20.0, 30.0, 40.0, 60.0] {
        for roll_off in [300.0, 3000.0] {
            let weight = PiWeight {
                crossover_rad_s: crossover,
                integral_corner_rad_s: crossover / 2.0,
                roll_off_rad_s: roll_off,
            }
            .for_plant(&plant)
            .expect("weight");
            let design = design(&plant, &weight, 1.1).expect("design");
            assert!(
                design.margins.closed_loop_stable,
                "{crossover} rad/s: {:?}",
                design.margins
            );
            if roll_off == 300.0 {
                assert!(design.gamma > previous_gamma, "{crossover} rad/s: γ {}", design.gamma);
                previous_gamma = design.gamma;
            }
        }
    }
}
