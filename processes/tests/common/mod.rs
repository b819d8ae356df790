//! What the process tests share.

use hydractl_bus::RunScope;

/// A shared-memory scope of the test's own, its files removed however the
/// test ends: a failed assert must not leave them for the next run.
pub struct TestScope(RunScope);

impl TestScope {
    pub fn new(name: &str) -> Self {
        let scope = RunScope::new(&format!("t{}_{name}_", std::process::id() % 100_000)).expect("prefix");
        scope.remove_all_files().expect("clean start");
        Self(scope)
    }
}

impl std::ops::Deref for TestScope {
    type Target = RunScope;
    fn deref(&self) -> &RunScope {
        &self.0
    }
}

impl Drop for TestScope {
    fn drop(&mut self) {
        let _ = self.0.remove_all_files();
    }
}
