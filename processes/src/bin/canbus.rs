//! The virtual CAN bus's wire. See [`hydractl_processes::process::canbus`].

fn main() -> anyhow::Result<()> {
    hydractl_processes::process::canbus::run()
}
