//! The hot path allocates nothing: one control period of the whole stack
//! and the plant's integration, counted by a global allocator.
#![allow(unsafe_code)] // A counting GlobalAlloc is unsafe by nature; it only forwards to System.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use hydractl_config::{Config, Structure, TorqueVariant};
use hydractl_control::VelocityMethod;
use hydractl_plant::{Effect, EffectKind};
use hydractl_sim::build_plant;
use hydractl_stages::ControlStack;

struct Counting;

thread_local! {
    // Only the thread under test counts, into its own counters: the test
    // harness and the other tests allocate on their own threads meanwhile.
    static COUNTING: Cell<bool> = const { Cell::new(false) };
    static ALLOCATIONS: Cell<usize> = const { Cell::new(0) };
    /// Bytes held by the thread under test, and the most it held.
    static LIVE_BYTES: Cell<usize> = const { Cell::new(0) };
    static PEAK_BYTES: Cell<usize> = const { Cell::new(0) };
}

fn count() {
    if COUNTING.with(Cell::get) {
        ALLOCATIONS.with(|a| a.set(a.get() + 1));
    }
}

fn held(grown: usize, freed: usize) {
    if COUNTING.with(Cell::get) {
        let live = LIVE_BYTES.with(|l| {
            let grown_to = l.get() + grown;
            l.set(grown_to.saturating_sub(freed));
            grown_to
        });
        PEAK_BYTES.with(|p| p.set(p.get().max(live)));
    }
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count();
        held(layout.size(), 0);
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        held(0, layout.size());
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count();
        held(new_size, layout.size());
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn a_control_period_allocates_nothing() {
    let all_effects: Vec<Effect> = EffectKind::ALL
        .iter()
        .map(|k| Effect::parse(k.name()).expect("defaults"))
        .collect();
    for (structure, torque, velocity) in [
        (Structure::Position, TorqueVariant::Pid, VelocityMethod::Differentiator),
        (Structure::Cascade, TorqueVariant::Pid, VelocityMethod::Differentiator),
        (Structure::Cascade, TorqueVariant::Hinf, VelocityMethod::Differentiator),
        (Structure::Cascade, TorqueVariant::Pid, VelocityMethod::Observer),
    ] {
        let mut config = Config::default_sim().expect("valid");
        config.control.structure = structure;
        config.control.torque_variant = torque;
        config.control.velocity_estimator.method = velocity;
        let (mut plant, mut sensor) = build_plant(&config, &all_effects).expect("plant");
        let mut stack = ControlStack::new(&config).expect("stack");
        let substeps = config.timing.substeps();
        let before = ALLOCATIONS.with(Cell::get);
        COUNTING.with(|c| c.set(true));
        for k in 0..2000 {
            let raw = sensor.read(&plant.state());
            let out = stack.step(k as f64 * 1e-3, &raw);
            plant.advance(out.command, substeps);
        }
        COUNTING.with(|c| c.set(false));
        let after = ALLOCATIONS.with(Cell::get);
        assert_eq!(after - before, 0, "{structure:?} / {torque:?} / {velocity:?} allocated");
    }
}

/// The most bytes the thread held while streaming `duration` seconds.
fn peak_bytes_streaming(duration: f64) -> usize {
    let config = Config::default_sim().expect("valid");
    LIVE_BYTES.with(|l| l.set(0));
    PEAK_BYTES.with(|p| p.set(0));
    COUNTING.with(|c| c.set(true));
    let mut rows = 0u64;
    let summary = hydractl_sim::simulate_streaming(&config, &[], duration, |_| {
        rows += 1;
        Ok(())
    });
    COUNTING.with(|c| c.set(false));
    assert_eq!(summary.expect("runs").cycles, rows);
    PEAK_BYTES.with(Cell::get)
}

#[test]
fn a_streamed_simulation_holds_the_same_memory_however_long_it_runs() {
    // Kept, 200 s of rows would take 200 000 × 120 bytes = 24 MB. Streamed,
    // a run holds one block of the torque's spectrum and its FFT plans,
    // whatever its length.
    const BOUND: usize = 2 * 1024 * 1024;
    for duration in [20.0, 200.0] {
        let peak = peak_bytes_streaming(duration);
        assert!(peak < BOUND, "{duration} s held {peak} bytes at most");
    }
}
