//! The position stage: the outer loop and the reference trajectory. See [`hydractl_processes::process::position`].

fn main() -> anyhow::Result<()> {
    hydractl_processes::process::position::run()
}
