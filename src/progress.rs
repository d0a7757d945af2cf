//! Progress reporting through a trait, so the library stays free of any
//! terminal code (the binary implements it with indicatif).

/// Receives progress of long stages. All methods default to doing nothing.
pub trait Progress: Send + Sync {
    /// A stage of `total` units starts.
    fn begin(&self, _stage: &str, _total: u64) {}
    /// `n` more units are done.
    fn advance(&self, _n: u64) {}
    /// The current stage is done.
    fn end(&self) {}
    /// A line of information for the user (what was repaired, a result, ...).
    fn note(&self, _line: &str) {}
}

/// Reports nothing.
#[derive(Clone, Copy, Debug, Default)]
pub struct Silent;

impl Progress for Silent {}

/// With `BTFQUILT_TRACE` set, notes how long it is since `start` that `what`
/// finished (a developer's timing trace; silent otherwise).
pub(crate) fn trace(progress: &dyn Progress, start: std::time::Instant, what: &str) {
    if std::env::var_os("BTFQUILT_TRACE").is_some() {
        progress.note(&format!("{what}: {:.3} s", start.elapsed().as_secs_f64()));
    }
}
