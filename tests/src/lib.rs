//! Workspace-level tests.
#[cfg(test)] mod metrics_reference;
