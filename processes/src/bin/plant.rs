//! The simulated rotator; see [`hydractl_processes::live_plant`].

fn main() -> anyhow::Result<()> {
    hydractl_processes::live_plant::run(hydractl_processes::live_plant::PlantKind::Simulation)
}
