//! The machine's stand-in: a plant with its own parameters and effects
//! (`[machine]` in the config); see [`hydractl_processes::live_plant`].

fn main() -> anyhow::Result<()> {
    hydractl_processes::live_plant::run(hydractl_processes::live_plant::PlantKind::Machine)
}
