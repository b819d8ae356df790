//! The sensor stage: the machine's readings to the sensor sample. See [`hydractl_processes::process::sensor`].

fn main() -> anyhow::Result<()> {
    hydractl_processes::process::sensor::run()
}
