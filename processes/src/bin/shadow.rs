//! The shadow model beside the machine. See [`hydractl_processes::process::shadow`].

fn main() -> anyhow::Result<()> {
    hydractl_processes::process::shadow::run()
}
