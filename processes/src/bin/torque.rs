//! The torque stage: the inner loop (the command passed through in position-only control). See [`hydractl_processes::process::torque`].

fn main() -> anyhow::Result<()> {
    hydractl_processes::process::torque::run()
}
