//! The quilting loop's rounds streamed (the loop of Fig. 4 a round at a
//! time, as in [`super::rounds`]): the thread that runs the loop, outside
//! the thread pool, chooses a round's work patches and hands each to the
//! pool as soon as it is chosen, then accepts them in order as they are
//! computed, so that choosing and accepting overlap the computing.

use std::sync::{Arc, Condvar, Mutex};

use super::rounds::{round_context, Chooser, Job};
use super::synthesis::{ledger, Synthesis};
use super::worker::{Outcome, Worker};
use crate::progress::{Progress, Silent};
use crate::Result;

impl Synthesis {
    /// A round of the quilting loop (as [`Synthesis::quilting_round`]
    /// chooses it, computed and accepted as [`Synthesis::compute`] and
    /// [`Synthesis::accept_steps`] do) with this thread, outside the pool,
    /// choosing, handing out and accepting while the pool computes: each
    /// work patch goes to the pool over views of its tiles as soon as it is
    /// chosen and memory holds it ([`Synthesis::patch_bytes`] within the
    /// patches' share of the loop's budget, [`Synthesis::settle_memory`],
    /// or none other in flight), and once
    /// the round is chosen the patches are accepted in order as they are
    /// computed, up to the first that read outside its tiles (that one and
    /// the rest are accepted after, as [`Synthesis::accept_steps`] does).
    /// A patch reads and writes only its own tiles, so the quilt is that of
    /// a round chosen, then computed, then accepted.
    pub(super) fn streamed_round(&mut self, radius0: usize, progress: &dyn Progress) -> Result<()> {
        let budget = self.patch_budget;
        let bytes = self.patch_bytes();
        let cost = |job: &Job| bytes(job.ball.texels.len());
        // whether a patch of `c` bytes may go with `in_flight` out
        let room = |in_flight: u64, c: u64| in_flight == 0 || in_flight + c <= budget;
        self.idle_main_matcher();
        let context = round_context!(self);
        let mut ledger = ledger!(self);
        let (bfs, surface, state) = (&mut self.bfs, &self.surface, &mut self.state);
        let mut chooser = Chooser::new(surface, self.cfg.round, radius0);
        let shared = Shared::default();
        let f = |w: &mut Worker<'_>, v: u32| w.step(v, radius0, &Silent);
        let (cx, sh, f) = (&context, &shared, &f);
        let mut jobs: Vec<Arc<Job>> = Vec::new();
        let mut accepted = 0;
        rayon::in_place_scope(|s| {
            let (mut choosing, mut accepting) = (true, true);
            let (mut handed, mut handed_bytes) = (0, 0u64);
            loop {
                // hand out what memory holds
                while handed < jobs.len() {
                    let c = cost(&jobs[handed]);
                    if !room(handed_bytes - crate::lock(&sh.round).freed, c) {
                        break;
                    }
                    let (j, job) = (handed, Arc::clone(&jobs[handed]));
                    let (surface, state) = (surface.view(job.view()), state.view(job.view()));
                    // (a task per patch, which never waits: a waiting
                    // task could hold up the pool's nested joins)
                    s.spawn(move |_| {
                        let _telling = Telling(sh);
                        let outcome = cx.run(j, &job, surface, state, f);
                        let mut round = crate::lock(&sh.round);
                        round.slots[j] = Some(outcome);
                        round.freed += c;
                    });
                    handed += 1;
                    handed_bytes += c;
                }
                if choosing {
                    // (all chosen from the state as the round found it)
                    match chooser.next(bfs, surface, state) {
                        Some(job) => {
                            jobs.push(Arc::new(job));
                            crate::lock(&sh.round).slots.push(None);
                        }
                        None => choosing = false,
                    }
                    continue;
                }
                let mut round = crate::lock(&sh.round);
                if round.panicked {
                    break;
                }
                if accepting && accepted < jobs.len() {
                    if let Some(outcome) = round.slots[accepted].take() {
                        drop(round);
                        match outcome {
                            Some(Ok(outcome)) => {
                                ledger.accept_outcome(state, surface, &outcome, progress);
                                accepted += 1;
                            }
                            other => {
                                // computed again, or its error met, in its turn
                                crate::lock(&sh.round).slots[accepted] = Some(other);
                                accepting = false;
                            }
                        }
                        continue;
                    }
                }
                if handed < jobs.len() {
                    // (memory freed since it was last looked at)
                    if room(handed_bytes - round.freed, cost(&jobs[handed])) {
                        continue;
                    }
                } else if accepted == jobs.len()
                    || (!accepting && round.slots[accepted..].iter().all(Option::is_some))
                {
                    break;
                }
                drop(sh.told.wait(round).unwrap_or_else(|e| e.into_inner()));
            }
        });
        let mut round = shared.round.into_inner().unwrap_or_else(|e| e.into_inner());
        let mut outcomes: Vec<Option<Result<Outcome>>> = round.slots[accepted..]
            .iter_mut()
            .map(|slot| slot.take().expect("every patch computed"))
            .collect();
        let rest = jobs.iter().map(AsRef::as_ref).enumerate().skip(accepted);
        self.recompute_narrow(&context, rest, &mut outcomes, f);
        if jobs.len() > 1 {
            self.report.concurrent_patches += jobs.len();
        }
        self.report.recomputed_patches += outcomes.iter().filter(|o| o.is_none()).count();
        self.spares = context.spares.into_inner().unwrap_or_else(|e| e.into_inner());
        self.accept_steps(jobs[accepted..].iter().map(|j| j.v), outcomes, radius0, progress)
    }
}

/// What the tasks of a streamed round share with the thread handing out
/// its work patches ([`Synthesis::streamed_round`]).
#[derive(Default)]
struct Shared {
    round: Mutex<Streamed>,
    /// Told when a patch is computed or its task panicked.
    told: Condvar,
}

#[derive(Default)]
struct Streamed {
    /// The outcome of each patch chosen, once computed.
    slots: Vec<Option<Option<Result<Outcome>>>>,
    /// The memory of the patches computed.
    freed: u64,
    panicked: bool,
}

/// Tells the thread handing out a streamed round when dropped: after a
/// task's patch, and when the task panics.
struct Telling<'a>(&'a Shared);

impl Drop for Telling<'_> {
    fn drop(&mut self) {
        let mut round = crate::lock(&self.0.round);
        round.panicked |= std::thread::panicking();
        self.0.told.notify_all();
    }
}
