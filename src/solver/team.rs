//! A team of rayon workers that shares a solve's parallel loops without putting threads to sleep.
//!
//! One relaxation iteration runs about six short parallel loops (the curvature gather, the force
//! gather, the step, the projection's passes, the direction update) separated by short serial
//! sections (the line search's test, the contact decisions). At 10k vertices a loop takes tens
//! of microseconds: rayon's fork-join hands each loop to a worker that has often gone to sleep
//! in between, and the futex round trip to wake it costs as much as the loop. A [`Team`]
//! instead keeps its helpers for the whole solve: they wait for the next loop spinning (and
//! running any other rayon job meanwhile). Code the solve calls on the leader's thread (its
//! projection) finds the team through [`Par::current`] and runs its own parallel loops on it
//! too.
//!
//! Each member owns a share of every loop: the `m`-th of as many contiguous runs of its chunks
//! as members, so the same vertices whatever the loop's chunk size. It claims its own chunks
//! from the front of its share (a quarter of those left at a time), and when its share is done
//! takes others' from the back of theirs: all of a share whose owner has not started on it,
//! but from a share whose owner is at work only while more chunks are left in it than half the
//! share (for a while: a member that stopped must not stall the loop). A chunk run on another core
//! than in the loop before moves its vertices between the cores' caches, and the loop after
//! reads them back: on session 27's machine a 10k-vertex force-gather chunk read after the
//! other core's step ran ~1.7x as long, more than the few microseconds the end of a loop waits
//! for the owner of a chunk instead of taking it.
//!
//! The results do not depend on who runs a chunk: each loop writes per-chunk outputs that are
//! summed in chunk order afterwards, exactly as with rayon's iterators, so a solve is
//! bit-identical for any number of threads. The leader never waits for a helper to arrive (a
//! share nobody started on is anyone's), only for the chunks a helper already claimed and,
//! briefly, for an owner at work on its share, so a team whose helpers are busy elsewhere (or a
//! pool of one thread) still runs, on the leader alone.
//!
//! A loop may carry a *rider* ([`Par::with_rider`]): another loop that reads nothing the first
//! writes, run in the same loop so that a member done with its part of one takes the other's.
//! A solve runs its projection pass (a few costly vertices near a collider, in one member's
//! share) with the force gather riding along (`SpringSystem::relax_projected`).
//!
//! A chunk that panics, on either side, is rethrown by the leader once every claimed chunk of
//! its loop is done (as a panic in a rayon loop reaches its caller): unwinding out of a helper
//! would leave the leader waiting for its chunks forever, and the leader unwinding at once would
//! free the loop's body while a helper still runs it.

use std::any::Any;
use std::cell::Cell;
use std::hint::spin_loop;
use std::marker::PhantomData;
use std::panic::{AssertUnwindSafe, catch_unwind, resume_unwind};
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicPtr, AtomicU64, AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use rayon::prelude::*;

/// How a loop over chunks runs: on rayon's pool (fork-join) or on a [`Team`].
#[derive(Clone, Copy)]
pub(crate) enum Par<'a> {
    /// `rayon`'s parallel iterators (outside a solve).
    Pool,
    /// The solve's team.
    Team(&'a Team),
}

impl Par<'_> {
    /// Calls `f(c)` once for every chunk `c` in `0..n`, in parallel.
    pub fn for_each(self, n: usize, f: impl Fn(usize) + Sync) {
        self.for_each_min(n, 1, f);
    }

    /// [`for_each`](Self::for_each), handing rayon's pool at least `min` chunks per task (a
    /// team ignores `min`: its helpers are awake, so a small chunk costs no wake-up).
    pub fn for_each_min(self, n: usize, min: usize, f: impl Fn(usize) + Sync) {
        match self {
            Par::Pool => (0..n).into_par_iter().with_min_len(min).for_each(&f),
            Par::Team(team) => team.run(n, &f),
        }
    }

    /// Runs `body` and the loop `rider` (`f(c)` for every chunk `c` in `0..n`) together: on a
    /// team, the first parallel loop `body` runs on it (through [`Par::current`]) runs the
    /// rider's chunks in the same loop, so whichever member is done with its part of one takes
    /// the other's, and the rider runs alone after `body` if `body` ran no loop on the team.
    /// On rayon's pool the rider runs after `body`. The two must not write what the other
    /// reads: their chunks run in any order and concurrently.
    pub fn with_rider<R>(
        self,
        n: usize,
        rider: &(dyn Fn(usize) + Sync),
        body: impl FnOnce() -> R,
    ) -> R {
        match self {
            Par::Pool => {
                let r = body();
                self.for_each(n, rider);
                r
            }
            Par::Team(team) => team.with_rider(n, rider, body),
        }
    }

    /// Runs `f` with the team of the solve this thread leads, outside that team's loops
    /// ([`Par::Pool`] anywhere else): a solve's callbacks (its projection) run their parallel
    /// loops on the solve's awake helpers instead of waking rayon's.
    pub fn current<R>(f: impl FnOnce(Par<'_>) -> R) -> R {
        let team = CURRENT.get();
        if team.is_null() {
            return f(Par::Pool);
        }
        // SAFETY: `CURRENT` names a team only while `Team::lead` runs the solve on this thread
        // (it restores the previous value before the team is dropped, unwinding included), and
        // never inside the team's own loops (`Team::run` clears it while it runs chunks).
        #[expect(unsafe_code, reason = "the team outlives the solve that set it")]
        f(Par::Team(unsafe { &*team }))
    }
}

thread_local! {
    /// The team whose solve this thread leads (null: none, or inside one of its loops).
    static CURRENT: Cell<*const Team> = const { Cell::new(std::ptr::null()) };
}

/// Restores [`CURRENT`] to what it was when dropped.
struct Restore(*const Team);

impl Drop for Restore {
    fn drop(&mut self) {
        CURRENT.set(self.0);
    }
}

/// One loop's body (on the leader's stack while the loop runs).
struct Job<'a> {
    f: &'a (dyn Fn(usize) + Sync),
}

/// A loop waiting to ride along the leader's next one (see [`Par::with_rider`]), on the
/// leader's stack while it waits.
struct Rider<'a> {
    n: usize,
    f: &'a (dyn Fn(usize) + Sync),
}

/// One member's share of the current loop, on cache lines of its own: the loop's number and
/// the share's unclaimed chunks `front..back` in one word (see [`LOOP_SHIFT`]).
#[repr(align(128))]
struct Share(AtomicU64);

/// A leader and the helpers it spawned on rayon's pool for one solve (see the module
/// documentation). The leader calls [`Team::run`] for each loop and [`Team::finish`] at the
/// end; helper `m` (from 1) calls [`Team::help`] once.
pub(crate) struct Team {
    /// Each member's share of the current loop, the leader's first: the `m`-th of as many
    /// contiguous runs of chunks as members.
    shares: Box<[Share]>,
    /// The current loop's number of chunks.
    chunks: AtomicUsize,
    /// Loops run so far (only the leader writes it).
    loops: AtomicU64,
    /// Chunks of the current loop finished by helpers.
    done: AtomicUsize,
    /// The current loop's [`Job`] (valid while any of its chunks is unclaimed or running).
    job: AtomicPtr<Job<'static>>,
    finished: AtomicBool,
    /// The first panic of a chunk a helper ran, rethrown by the leader once the loop is done.
    panic: Mutex<Option<Box<dyn Any + Send>>>,
    /// Whether `panic` holds one (so the leader locks it only then, not after every loop).
    panicked: AtomicBool,
    /// The loop to run with the leader's next one (null: none); only the leader touches it.
    rider: AtomicPtr<Rider<'static>>,
    /// Whether the current loop carries a rider: a member done with its share then leaves an
    /// owner at work only its last chunk, not half its share.
    eager: AtomicBool,
}

/// Where `back` starts in a share's word, above `front` (24 bits each).
const BACK_SHIFT: u32 = 24;
/// Where the loop's number (its low 16 bits) starts in a share's word, above `back`.
const LOOP_SHIFT: u32 = 48;
/// Chunks a loop may have.
const MAX_CHUNKS: usize = 1 << BACK_SHIFT;
const SPAN: u64 = MAX_CHUNKS as u64 - 1;

/// The first unclaimed chunk of a share's word.
fn front(s: u64) -> u64 {
    s & SPAN
}

/// The end of the unclaimed chunks of a share's word.
fn back(s: u64) -> u64 {
    (s >> BACK_SHIFT) & SPAN
}

/// How long a member waits for another member at work on its share to claim the chunks it
/// keeps before it takes them itself (a member that stopped, preempted or gone elsewhere, must
/// not stall the loop): several times the longest chunk here (~10 µs).
const PATIENCE: Duration = Duration::from_micros(50);

/// A member's wait for the chunks another member keeps: patient until [`PATIENCE`] has passed
/// since the wait began.
#[derive(Default)]
struct Patience {
    /// When the wait ends (none until it begins).
    until: Option<Instant>,
    /// Whether it has ended.
    over: bool,
}

impl Patience {
    /// Whether the member still leaves others the chunks they keep.
    fn patient(&self) -> bool {
        !self.over
    }

    /// Notes one more turn of waiting (the first one begins the wait).
    fn waited(&mut self) {
        let now = Instant::now();
        self.over = now >= *self.until.get_or_insert(now + PATIENCE);
    }
}

/// Chunks one claim takes when `left` are unclaimed: a quarter of them, at least one. Claiming a
/// quarter at a time costs a share of `n` chunks O(log n) claims instead of `n`, and the last
/// chunks still go one by one, which keeps the members' loads even.
fn batch(left: u64) -> u64 {
    (left / 4).max(1)
}

/// What a member found when it looked for chunks to run.
enum Claim {
    /// These chunks are now its to run.
    Chunks(std::ops::Range<u64>),
    /// Only chunks another member at work on its share will soon claim are left.
    Wait,
    /// Every chunk of the loop is claimed.
    Empty,
}

impl Team {
    /// A team of `members`: the leader and `members - 1` helpers.
    pub fn new(members: usize) -> Self {
        Self {
            shares: (0..members.max(1))
                .map(|_| Share(AtomicU64::new(0)))
                .collect(),
            chunks: AtomicUsize::new(0),
            loops: AtomicU64::new(0),
            done: AtomicUsize::new(0),
            job: AtomicPtr::new(std::ptr::null_mut()),
            finished: AtomicBool::new(false),
            panic: Mutex::new(None),
            panicked: AtomicBool::new(false),
            rider: AtomicPtr::new(std::ptr::null_mut()),
            eager: AtomicBool::new(false),
        }
    }

    /// Member `me`'s next chunks: from the front of its own share, or else from the back of
    /// another's of the same loop (see the module documentation). While `patient`, it leaves a
    /// member at work on its share (one that claimed from it in this loop) as many unclaimed
    /// chunks as half that share. The acquire of a successful claim pairs with [`publish`](Self::publish).
    fn claim(&self, me: usize, patient: bool) -> Claim {
        let own = &self.shares[me].0;
        // Acquire: the loop's `chunks` is seen with its shares.
        let mut s = own.load(Ordering::Acquire);
        let loop_id = s >> LOOP_SHIFT;
        while front(s) < back(s) {
            let k = batch(back(s) - front(s));
            match own.compare_exchange_weak(s, s + k, Ordering::Acquire, Ordering::Relaxed) {
                Ok(_) => return Claim::Chunks(front(s)..front(s) + k),
                Err(now) => s = now,
            }
        }
        let members = self.shares.len();
        let n = self.chunks.load(Ordering::Relaxed) as u64;
        let mut wait = false;
        for v in (1..members).map(|o| (me + o) % members) {
            let share = &self.shares[v].0;
            // Where its owner starts, and how many chunks it keeps while it is at work.
            let start = v as u64 * n / members as u64;
            let end = (v as u64 + 1) * n / members as u64;
            let keep = if self.eager.load(Ordering::Relaxed) {
                1
            } else {
                (end - start).div_ceil(2).max(1)
            };
            let mut s = share.load(Ordering::Relaxed);
            // Only a share of the loop this member's own share is from: a share of the next
            // loop, published after this member read its own, is its owner's to start.
            while s >> LOOP_SHIFT == loop_id && front(s) < back(s) {
                let (front, back) = (front(s), back(s));
                let spare = if patient && front > start {
                    (back - front).saturating_sub(keep)
                } else {
                    back - front
                };
                if spare == 0 {
                    wait = true;
                    break;
                }
                let k = batch(spare);
                match share.compare_exchange_weak(
                    s,
                    s - (k << BACK_SHIFT),
                    Ordering::Acquire,
                    Ordering::Relaxed,
                ) {
                    Ok(_) => return Claim::Chunks(back - k..back),
                    Err(now) => s = now,
                }
            }
        }
        if wait { Claim::Wait } else { Claim::Empty }
    }

    /// Hands out a loop of `n` chunks: member `m` owns the `m`-th of the contiguous shares.
    /// The release pairs with a claim's acquire: a member that claims a chunk of this loop sees
    /// everything the leader wrote before (its job).
    fn publish(&self, n: usize) {
        self.chunks.store(n, Ordering::Relaxed);
        let members = self.shares.len() as u64;
        let loop_id = self.loops.fetch_add(1, Ordering::Relaxed) & 0xffff;
        for (m, share) in self.shares.iter().enumerate().rev() {
            let m = m as u64;
            let (front, back) = (m * n as u64 / members, (m + 1) * n as u64 / members);
            share.0.store(
                (loop_id << LOOP_SHIFT) | (back << BACK_SHIFT) | front,
                Ordering::Release,
            );
        }
    }

    /// [`Par::with_rider`] on this team. Only the leader may call it.
    fn with_rider<R>(&self, n: usize, f: &(dyn Fn(usize) + Sync), body: impl FnOnce() -> R) -> R {
        /// Takes the rider back however `body` ends (a panic included), so that no later loop
        /// runs it after its frame is gone.
        struct Unride<'a>(&'a Team);
        impl Drop for Unride<'_> {
            fn drop(&mut self) {
                self.0.rider.store(std::ptr::null_mut(), Ordering::Relaxed);
            }
        }
        let rider = Rider { n, f };
        // Only the lifetime is erased: `run` dereferences it only while `body` runs (below),
        // within this frame, and `Unride` clears it before the frame ends.
        let ptr = (&raw const rider).cast::<Rider<'static>>().cast_mut();
        let previous = self.rider.swap(ptr, Ordering::Relaxed);
        debug_assert!(previous.is_null(), "one rider at a time");
        let _unride = Unride(self);
        let r = body();
        // A loop that took the rider cleared it; else `body` ran no loop on the team, and the
        // rider runs alone.
        if std::ptr::eq(
            self.rider.swap(std::ptr::null_mut(), Ordering::Relaxed),
            ptr,
        ) {
            self.run_alone(n, f);
        }
        r
    }

    /// Runs `f(c)` for every chunk `c` in `0..n`, on the leader and whichever helpers are
    /// waiting; returns when all have finished. Only the leader may call it. A loop waiting
    /// to ride along ([`Par::with_rider`]) runs in the same loop: each member's share holds
    /// the chunks of `f` its share of `f` alone would hold, then the rider's likewise (so the
    /// vertices stay on their cores), and a member done with its share takes another's
    /// chunks from its back down to the last one, not only half of it: the two loops'
    /// work rarely splits evenly between the shares (a projection's few costly vertices sit
    /// in one), and the rider's chunks at the back even it out.
    pub fn run(&self, n: usize, f: &(dyn Fn(usize) + Sync)) {
        let rider = self.rider.swap(std::ptr::null_mut(), Ordering::Relaxed);
        if rider.is_null() {
            return self.run_alone(n, f);
        }
        self.eager.store(true, Ordering::Relaxed);
        struct Calm<'a>(&'a Team);
        impl Drop for Calm<'_> {
            fn drop(&mut self) {
                self.0.eager.store(false, Ordering::Relaxed);
            }
        }
        let _calm = Calm(self);
        // SAFETY: a rider is stored only while `with_rider` runs its body, which called this
        // (only the leader runs loops), and its frame holds the rider.
        #[expect(
            unsafe_code,
            reason = "the rider outlives the body that runs this loop"
        )]
        let Rider { n: m, f: g } = *unsafe { &*rider };
        // Member `k`'s share: its chunks of `f` (those `f` alone would give it), then its
        // chunks of the rider (the same): the owner starts on `f`'s, and a member done with its
        // share takes the rider's from the back of another's.
        let members = self.shares.len();
        let start = |k: usize| (k * n / members, k * m / members);
        self.run_alone(n + m, &|c| {
            let k = (1..members)
                .take_while(|&k| {
                    let (a, b) = start(k);
                    a + b <= c
                })
                .last()
                .unwrap_or(0);
            let ((a, b), (a_end, _)) = (start(k), start(k + 1));
            let local = c - a - b;
            if local < a_end - a {
                f(a + local);
            } else {
                g(b + local - (a_end - a));
            }
        });
    }

    /// [`run`](Self::run) without a rider.
    fn run_alone(&self, n: usize, f: &(dyn Fn(usize) + Sync)) {
        assert!(n < MAX_CHUNKS, "too many chunks for one loop");
        let job = Job { f };
        // Only the lifetime is erased: helpers dereference the pointer only after claiming a
        // chunk (below), and this function does not return before every claimed chunk is done,
        // so `job` outlives every use.
        let ptr = (&raw const job).cast::<Job<'static>>().cast_mut();
        self.done.store(0, Ordering::Relaxed);
        self.job.store(ptr, Ordering::Relaxed);
        self.publish(n);
        // A chunk that asks for the current team runs its loops on rayon's pool: the team
        // runs one loop at a time.
        let _restore = Restore(CURRENT.replace(std::ptr::null()));
        let mut mine = 0;
        // A chunk that panics does not end the loop at once: the helpers may still be running
        // chunks of it, through `job`. The rest of the loop is claimed (and skipped), the
        // helpers' chunks awaited, and the first panic rethrown then.
        let mut panic = None;
        let mut patience = Patience::default();
        loop {
            match self.claim(0, patience.patient()) {
                Claim::Chunks(claimed) => {
                    mine += (claimed.end - claimed.start) as usize;
                    for c in claimed {
                        if panic.is_none() {
                            panic = catch_unwind(AssertUnwindSafe(|| f(c as usize))).err();
                        }
                    }
                }
                Claim::Wait => {
                    patience.waited();
                    spin_loop();
                }
                Claim::Empty => break,
            }
        }
        // Every chunk is claimed; wait for the ones the helpers run.
        let mut spins = 0u32;
        while self.done.load(Ordering::Acquire) < n - mine {
            spins += 1;
            if spins < 1 << 12 {
                spin_loop();
            } else {
                std::thread::yield_now();
            }
        }
        // The acquire of `done` above sees a helper's flag set before its `done` release.
        if panic.is_none() && self.panicked.swap(false, Ordering::Relaxed) {
            panic = self.panic.lock().unwrap_or_else(|e| e.into_inner()).take();
        }
        if let Some(payload) = panic {
            resume_unwind(payload);
        }
    }

    /// Helper `me`'s loop (from 1): claims chunks of the leader's loops until
    /// [`finish`](Self::finish). While there is nothing to claim it spins, runs other rayon
    /// jobs, and yields its CPU.
    #[expect(
        unsafe_code,
        reason = "dereferences the leader's job, kept alive until this helper's chunk is done"
    )]
    pub fn help(&self, me: usize) {
        let (mut idle, mut patience) = (0u32, Patience::default());
        while !self.finished.load(Ordering::Acquire) {
            match self.claim(me, patience.patient()) {
                Claim::Chunks(claimed) => {
                    // SAFETY: the claimed chunks of the loop whose share this was are not
                    // done, so the leader is inside `run` for that loop and its job is alive;
                    // the pointer was stored before the loop was published (the claim's
                    // acquire).
                    let job = unsafe { &*self.job.load(Ordering::Relaxed) };
                    let k = (claimed.end - claimed.start) as usize;
                    for c in claimed {
                        // A panic is handed to the leader (see `run`): unwinding out of here
                        // would leave the leader waiting for these chunks forever.
                        if let Err(payload) = catch_unwind(AssertUnwindSafe(|| (job.f)(c as usize)))
                        {
                            self.panic
                                .lock()
                                .unwrap_or_else(|e| e.into_inner())
                                .get_or_insert(payload);
                            self.panicked.store(true, Ordering::Relaxed);
                        }
                    }
                    self.done.fetch_add(k, Ordering::Release);
                    (idle, patience) = (0, Patience::default());
                }
                Claim::Wait => {
                    patience.waited();
                    spin_loop();
                }
                Claim::Empty => {
                    patience = Patience::default();
                    idle += 1;
                    if idle < 1 << 8 {
                        spin_loop();
                    } else if rayon::yield_now() != Some(rayon::Yield::Executed) && idle > 1 << 12 {
                        std::thread::yield_now();
                    }
                }
            }
        }
    }

    /// Ends the team: the helpers return from [`help`](Self::help).
    pub fn finish(&self) {
        self.finished.store(true, Ordering::Release);
    }

    /// Runs `solve` as the leader of a team with one helper per other thread of the current
    /// rayon pool, at most `max_helpers` (a solve whose loops have one chunk needs none: a
    /// helper would only spin, and keep its thread from other work such as other solves). The
    /// helpers are released however `solve` ends, a panic included (which then propagates).
    pub fn lead<R: Send>(max_helpers: usize, solve: impl FnOnce(&Team) -> R + Send) -> R {
        /// Ends the team when the leader's solve ends, by return or by unwinding.
        struct Finish<'a>(&'a Team);
        impl Drop for Finish<'_> {
            fn drop(&mut self) {
                self.0.finish();
            }
        }
        let helpers = max_helpers.min(rayon::current_num_threads() - 1);
        let team = Team::new(1 + helpers);
        rayon::scope(|s| {
            for me in 1..=helpers {
                let team = &team;
                s.spawn(move |_| team.help(me));
            }
            let _finish = Finish(&team);
            let _restore = Restore(CURRENT.replace(&raw const team));
            solve(&team)
        })
    }
}

/// A slice split into chunks that the chunks of a parallel loop write, each its own.
pub(crate) struct Chunked<'a, T> {
    ptr: *mut T,
    len: usize,
    size: usize,
    _borrow: PhantomData<&'a mut [T]>,
}

// SAFETY: a `Chunked` hands out disjoint chunks of a slice it borrows mutably; it is as
// shareable as `&mut [T]` is sendable.
#[expect(unsafe_code, reason = "disjoint chunks of a mutably borrowed slice")]
unsafe impl<T: Send> Sync for Chunked<'_, T> {}
#[expect(unsafe_code, reason = "disjoint chunks of a mutably borrowed slice")]
unsafe impl<T: Send> Send for Chunked<'_, T> {}

impl<'a, T> Chunked<'a, T> {
    /// `data` in chunks of `size` elements (the last one may be shorter).
    pub fn new(data: &'a mut [T], size: usize) -> Self {
        Self {
            ptr: data.as_mut_ptr(),
            len: data.len(),
            size,
            _borrow: PhantomData,
        }
    }

    /// Number of chunks.
    pub fn chunks(&self) -> usize {
        self.len.div_ceil(self.size)
    }

    /// Chunk `c` (empty past the end).
    ///
    /// # Safety
    /// No two live references to the same chunk: within one parallel loop each chunk index is
    /// handed to one call only ([`Par::for_each`]).
    #[expect(unsafe_code, reason = "disjoint chunks of a mutably borrowed slice")]
    #[expect(
        clippy::mut_from_ref,
        reason = "each chunk is handed out once per loop"
    )]
    pub unsafe fn chunk(&self, c: usize) -> &mut [T] {
        let start = (c * self.size).min(self.len);
        let end = (start + self.size).min(self.len);
        // SAFETY: `start..end` lies in the borrowed slice, and the caller guarantees no other
        // reference to this chunk is live.
        unsafe { std::slice::from_raw_parts_mut(self.ptr.add(start), end - start) }
    }
}

#[cfg(test)]
mod tests {
    use std::sync::atomic::{AtomicUsize, Ordering};

    use super::*;

    fn pool(threads: usize) -> rayon::ThreadPool {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
    }

    /// Runs `loops` loops of varying sizes (0 included) on a team and checks that every chunk of
    /// every loop ran exactly once, with the right loop's body.
    fn every_chunk_once(threads: usize, helpers: usize, loops: usize) {
        pool(threads).install(|| {
            Team::lead(helpers, |team| {
                for l in 0..loops {
                    let n = (l * 7) % 23;
                    let hits: Vec<AtomicUsize> = (0..n).map(|_| AtomicUsize::new(0)).collect();
                    Par::Team(team).for_each(n, |c| {
                        hits[c].fetch_add(l + 1, Ordering::Relaxed);
                    });
                    for (c, h) in hits.iter().enumerate() {
                        assert_eq!(h.load(Ordering::Relaxed), l + 1, "loop {l} chunk {c}");
                    }
                }
            });
        });
    }

    #[test]
    fn every_chunk_of_every_loop_runs_once_on_one_to_four_threads() {
        for threads in [1, 2, 4] {
            every_chunk_once(threads, usize::MAX, 3_000);
        }
        // A team without helpers (a one-chunk solve's) runs everything on the leader.
        every_chunk_once(2, 0, 300);
    }

    /// A rider joins the first loop its body runs on the team (every chunk of both once, the
    /// rider's all done when that loop returns), runs alone after a body that ran no loop,
    /// and runs after the body on rayon's pool; loops after the first do not run it again.
    #[test]
    fn a_rider_runs_once_with_the_body_s_first_loop_or_after_the_body() {
        for threads in [1, 2, 3, 4] {
            pool(threads).install(|| {
                Team::lead(usize::MAX, |team| {
                    for l in 0..400 {
                        // Both sizes equal, then different (the shares split each its own way).
                        let (n, m) = ((l * 7) % 23, if l % 2 == 0 { (l * 7) % 23 } else { l % 13 });
                        let body: Vec<AtomicUsize> = (0..n).map(|_| AtomicUsize::new(0)).collect();
                        let rider: Vec<AtomicUsize> = (0..m).map(|_| AtomicUsize::new(0)).collect();
                        let rider_done = || {
                            rider
                                .iter()
                                .map(|h| h.load(Ordering::Relaxed))
                                .sum::<usize>()
                        };
                        let runs_a_loop = l % 3 != 0;
                        let seen = Par::Team(team).with_rider(
                            m,
                            &|c| {
                                rider[c].fetch_add(1, Ordering::Relaxed);
                            },
                            || {
                                if !runs_a_loop {
                                    return rider_done();
                                }
                                Par::current(|par| {
                                    par.for_each(n, |c| {
                                        body[c].fetch_add(1, Ordering::Relaxed);
                                    });
                                    let after_first = rider_done();
                                    par.for_each(n, |c| {
                                        body[c].fetch_add(1, Ordering::Relaxed);
                                    });
                                    after_first
                                })
                            },
                        );
                        let expected = if runs_a_loop { m } else { 0 };
                        assert_eq!(seen, expected, "loop {l}: the rider's chunks in the body");
                        assert!(
                            rider.iter().all(|h| h.load(Ordering::Relaxed) == 1),
                            "loop {l}"
                        );
                        let twice = if runs_a_loop { 2 } else { 0 };
                        assert!(
                            body.iter().all(|h| h.load(Ordering::Relaxed) == twice),
                            "loop {l}"
                        );
                    }
                });
                // On rayon's pool: after the body.
                let hits: Vec<AtomicUsize> = (0..9).map(|_| AtomicUsize::new(0)).collect();
                let during = Par::Pool.with_rider(
                    9,
                    &|c| {
                        hits[c].fetch_add(1, Ordering::Relaxed);
                    },
                    || {
                        hits.iter()
                            .map(|h| h.load(Ordering::Relaxed))
                            .sum::<usize>()
                    },
                );
                assert_eq!(during, 0);
                assert!(hits.iter().all(|h| h.load(Ordering::Relaxed) == 1));
            });
        }
    }

    /// The chunks a claim handed out, if any.
    fn chunks(c: Claim) -> Option<std::ops::Range<u64>> {
        match c {
            Claim::Chunks(r) => Some(r),
            Claim::Wait | Claim::Empty => None,
        }
    }

    #[test]
    fn members_claim_their_own_share_first_and_leave_one_at_work_half_of_its_share() {
        let team = Team::new(2);
        team.publish(10);
        // Own shares (0..5, 5..10) from the front, a quarter of what is left at a time.
        assert_eq!(chunks(team.claim(0, true)), Some(0..1));
        assert_eq!(chunks(team.claim(1, true)), Some(5..6));
        for c in 1..5 {
            assert_eq!(chunks(team.claim(0, true)), Some(c..c + 1));
        }
        // The helper is at work with four chunks left: it keeps three (half its share), the
        // leader takes the last one.
        assert_eq!(chunks(team.claim(0, true)), Some(9..10));
        // Then the leader waits while it is patient, and takes the rest when it is not.
        assert!(matches!(team.claim(0, true), Claim::Wait));
        assert_eq!(chunks(team.claim(0, false)), Some(8..9));
        assert_eq!(chunks(team.claim(1, true)), Some(6..7));
        assert_eq!(chunks(team.claim(1, true)), Some(7..8));
        for me in 0..2 {
            assert!(matches!(team.claim(me, true), Claim::Empty));
        }
        // A team of one claims everything, a quarter at a time.
        let alone = Team::new(1);
        alone.publish(9);
        let got: Vec<_> = std::iter::from_fn(|| chunks(alone.claim(0, true))).collect();
        assert_eq!(got, [0..2, 2..3, 3..4, 4..5, 5..6, 6..7, 7..8, 8..9]);
    }

    #[test]
    fn a_share_nobody_started_on_is_anyone_s_and_another_loop_s_is_left_alone() {
        let team = Team::new(3);
        team.publish(12);
        // Shares 0..4, 4..8, 8..12: the leader does its own, helper 1 starts on its own,
        // helper 2 never comes.
        for c in 0..4 {
            assert_eq!(chunks(team.claim(0, true)), Some(c..c + 1));
        }
        assert_eq!(chunks(team.claim(1, true)), Some(4..5));
        // Helper 1 keeps two of its three left; helper 2's share goes whole, from the back.
        assert_eq!(chunks(team.claim(0, true)), Some(7..8));
        assert_eq!(chunks(team.claim(0, true)), Some(11..12));
        assert_eq!(chunks(team.claim(1, true)), Some(5..6));
        assert_eq!(chunks(team.claim(1, true)), Some(6..7));
        assert_eq!(chunks(team.claim(1, true)), Some(10..11));
        // A member whose own share it last saw is from an earlier loop does not take chunks
        // of the next one (their owners' to start).
        team.publish(12);
        let earlier = (team.shares[2].0.load(Ordering::Relaxed) >> LOOP_SHIFT) - 1;
        let done = (earlier << LOOP_SHIFT) | (12 << BACK_SHIFT) | 12;
        team.shares[2].0.store(done, Ordering::Relaxed);
        assert!(matches!(team.claim(2, true), Claim::Empty));
        assert_eq!(chunks(team.claim(1, true)), Some(4..5));
        // Loop numbers wrap around (16 bits): a loop after the wrap is handed out as any.
        team.loops.store(0xffff, Ordering::Relaxed);
        team.publish(2);
        team.publish(2);
        assert_eq!(team.shares[0].0.load(Ordering::Relaxed) >> LOOP_SHIFT, 0);
        // Shares 0..0, 0..1, 1..2.
        assert_eq!(chunks(team.claim(1, true)), Some(0..1));
        assert_eq!(chunks(team.claim(0, true)), Some(1..2));
        assert!(matches!(team.claim(2, true), Claim::Empty));
    }

    #[test]
    fn chunked_writes_reach_the_leader() {
        pool(2).install(|| {
            let mut data = vec![0u32; 1000];
            Team::lead(usize::MAX, |team| {
                for round in 1..200u32 {
                    let chunks = Chunked::new(&mut data, 64);
                    Par::Team(team).for_each(chunks.chunks(), |c| {
                        // SAFETY: each chunk index once per loop.
                        #[expect(unsafe_code, reason = "the test of `Chunked`")]
                        let chunk = unsafe { chunks.chunk(c) };
                        for v in chunk {
                            *v += round;
                        }
                    });
                    // Every element saw every round so far (the helpers' writes are visible).
                    let expected = round * (round + 1) / 2;
                    assert!(data.iter().all(|&v| v == expected), "round {round}");
                }
            });
        });
    }

    #[test]
    fn a_panicking_solve_releases_its_helpers_and_propagates() {
        // Without the release the helpers would spin forever and the scope would never end.
        let caught = pool(2).install(|| {
            std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                Team::lead(usize::MAX, |team| {
                    Par::Team(team).for_each(4, |_| {});
                    panic!("a bug in a solve");
                })
            }))
        });
        assert!(caught.is_err());
    }

    /// The team `Par::current` hands out: `Some(address)` or `None` for rayon's pool.
    fn current_team() -> Option<usize> {
        Par::current(|par| match par {
            Par::Pool => None,
            Par::Team(team) => Some(std::ptr::from_ref(team) as usize),
        })
    }

    #[test]
    fn the_current_team_is_the_solve_s_own_and_only_outside_its_loops() {
        pool(2).install(|| {
            assert_eq!(current_team(), None);
            Team::lead(usize::MAX, |team| {
                let me = Some(std::ptr::from_ref(team) as usize);
                assert_eq!(current_team(), me);
                // Inside the team's own loop (leader or helper) a chunk gets rayon's pool: a
                // nested loop on the team would corrupt the running one.
                let inside: Vec<AtomicUsize> = (0..8).map(|_| AtomicUsize::new(1)).collect();
                Par::Team(team).for_each(8, |c| {
                    inside[c].store(usize::from(current_team().is_some()), Ordering::Relaxed);
                });
                assert!(inside.iter().all(|v| v.load(Ordering::Relaxed) == 0));
                assert_eq!(current_team(), me);
                // A solve led inside this one has its own team, and this one's comes back.
                Team::lead(usize::MAX, |inner| {
                    assert_eq!(current_team(), Some(std::ptr::from_ref(inner) as usize));
                });
                assert_eq!(current_team(), me);
                // The current team runs loops like the solve's own.
                let hits: Vec<AtomicUsize> = (0..16).map(|_| AtomicUsize::new(0)).collect();
                Par::current(|par| {
                    par.for_each_min(16, 4, |c| {
                        hits[c].fetch_add(1, Ordering::Relaxed);
                    })
                });
                assert!(hits.iter().all(|h| h.load(Ordering::Relaxed) == 1));
            });
            assert_eq!(current_team(), None);
            // Unwinding out of a solve restores it too.
            let caught = std::panic::catch_unwind(|| {
                Team::lead(usize::MAX, |_| panic!("a bug in a solve"));
            });
            assert!(caught.is_err());
            assert_eq!(current_team(), None);
        });
    }

    #[test]
    fn a_panicking_chunk_propagates_once_its_loop_is_done_on_either_thread() {
        // A chunk panicking on a helper must reach the leader (unwinding out of the helper
        // would leave the leader waiting for it forever), and one panicking on the leader must
        // wait for the helper's chunks, which still run through the leader's loop body.
        for helper_panics in [false, true] {
            let (tx, rx) = std::sync::mpsc::channel();
            std::thread::spawn(move || {
                let caught = pool(2).install(|| {
                    std::panic::catch_unwind(|| {
                        Team::lead(usize::MAX, |team| {
                            let leader = std::thread::current().id();
                            for _ in 0..50 {
                                Par::Team(team).for_each(64, |c| {
                                    // Slow chunks: the helper takes part in every loop.
                                    std::thread::sleep(std::time::Duration::from_micros(50));
                                    let on_leader = std::thread::current().id() == leader;
                                    if on_leader != helper_panics && c % 7 == 3 {
                                        panic!("chunk {c}");
                                    }
                                });
                            }
                        });
                    })
                });
                let _ = tx.send(caught.is_err());
            });
            let panicked = rx.recv_timeout(std::time::Duration::from_secs(30));
            assert_eq!(panicked, Ok(true), "helper panics: {helper_panics}");
        }
    }

    #[test]
    fn teams_nested_in_a_parallel_loop_all_finish() {
        // Four solves in parallel on two threads: a helper may run inside another team's wait
        // (work stealing); nobody waits for a helper to arrive, so all finish.
        pool(2).install(|| {
            let sums: Vec<usize> = (0..4usize)
                .into_par_iter()
                .map(|t| {
                    Team::lead(usize::MAX, |team| {
                        let total = AtomicUsize::new(0);
                        for _ in 0..500 {
                            Par::Team(team).for_each(8, |c| {
                                total.fetch_add(c + t, Ordering::Relaxed);
                            });
                        }
                        total.load(Ordering::Relaxed)
                    })
                })
                .collect();
            for (t, s) in sums.iter().enumerate() {
                assert_eq!(*s, 500 * (28 + 8 * t));
            }
        });
    }
}
