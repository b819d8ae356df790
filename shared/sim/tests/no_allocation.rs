//! The hot path allocates nothing: one control period of the whole stack
//! and the plant's integration, counted by a global allocator.
#![allow(unsafe_code)] // A counting GlobalAlloc is unsafe by nature; it only forwards to System.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicUsize, Ordering};

use hydractl_config::{Config, Structure, TorqueVariant};
use hydractl_plant::{Effect, EffectKind};
use hydractl_sim::build_plant;
use hydractl_stages::ControlStack;

struct Counting;

static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

thread_local! {
    // Only the thread under test counts: the test harness allocates on its
    // own threads while a test runs.
    static COUNTING: Cell<bool> = const { Cell::new(false) };
}

fn count() {
    if COUNTING.with(Cell::get) {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
    }
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count();
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count();
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
    for (structure, torque) in [
        (Structure::Position, TorqueVariant::Pid),
        (Structure::Cascade, TorqueVariant::Pid),
        (Structure::Cascade, TorqueVariant::Hinf),
    ] {
        let mut config = Config::default_sim().expect("valid");
        config.control.structure = structure;
        config.control.torque_variant = torque;
        let (mut plant, mut sensor) = build_plant(&config, &all_effects).expect("plant");
        let mut stack = ControlStack::new(&config).expect("stack");
        let substeps = config.timing.substeps();
        let before = ALLOCATIONS.load(Ordering::Relaxed);
        COUNTING.with(|c| c.set(true));
        for k in 0..2000 {
            let raw = sensor.read(&plant.state());
            let out = stack.step(k as f64 * 1e-3, &raw);
            plant.advance(out.command, substeps);
        }
        COUNTING.with(|c| c.set(false));
        let after = ALLOCATIONS.load(Ordering::Relaxed);
        assert_eq!(after - before, 0, "{structure:?} / {torque:?} allocated");
    }
}
