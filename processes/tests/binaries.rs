//! The process binaries exist (and so `cargo test` builds them for the
//! system tests in the workspace's `tests/`).

#[test]
fn every_process_binary_is_built() {
    for path in [
        env!("CARGO_BIN_EXE_plant"),
        env!("CARGO_BIN_EXE_sensor"),
        env!("CARGO_BIN_EXE_friction"),
        env!("CARGO_BIN_EXE_position"),
        env!("CARGO_BIN_EXE_torque"),
        env!("CARGO_BIN_EXE_valve"),
        env!("CARGO_BIN_EXE_supervisor"),
    ] {
        assert!(std::path::Path::new(path).exists(), "{path}");
    }
}
