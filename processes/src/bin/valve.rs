//! The valve stage: command shaping and the last line of safety. See [`hydractl_processes::process::valve`].

fn main() -> anyhow::Result<()> {
    hydractl_processes::process::valve::run()
}
