//! The CPU stepper's SPH force stage with each pair evaluated once (tlsph).
//!
//! tlsph's pair terms are antisymmetric: on particle c from the pair (c, b) they are V²(A_c +
//! A_b)∇W(X_b − X_c) plus the hourglass term along x_cb, and b gets their negatives (∇W is
//! odd; the hourglass term changes sign with x_cb and X_cb). `sph_forces`, the kernel's twin,
//! visits every pair from both ends, as one GPU thread per particle must; a CPU can do each
//! pair once. Each activation lists the pairs that carry a force (both particles in the force
//! set F, at least one in S) once, grouped by the particle that owns them: the one in S, or
//! the lower index when both are. Each step computes the pairs (in parallel over their owners)
//! and every particle of F sums its pairs in its neighbour-list order, with its end's sign,
//! then adds gravity and the tool's contact as the kernel does. The terms are the kernel's,
//! from each particle's quantities packed once per step (V²A, F, u in an aligned record per
//! particle); the products are grouped differently ((V²A_c + V²A_b)∇W, (F_c + F_b)X_cb) and
//! the hourglass term's relative position is rounded once instead of at each end, so the
//! forces equal the twin's to rounding (tested), and the two ends of a pair get exactly
//! opposite forces.

use super::load3a;
use super::sph::PairTable;
use super::sph_forces::{add_external, load_mat3a, store_forces, ForceInputs};
use crate::particles::params::mode;
use glam::{Mat3A, Vec3, Vec3A};
use std::sync::atomic::{AtomicU64, Ordering};

/// Source of [`PairPlan`] build numbers, unique over every plan of the process (a restored
/// plan keeps its number; the records of another build never pass for its own).
static NEXT_BUILD: AtomicU64 = AtomicU64::new(1);

/// Per neighbour slot k of particle c (neighbour b), the slot of c in b's list (the lists are
/// symmetric: |X_b − X_c| is the same either way round). Built once with the lists.
pub fn transpose_slots(neighbour_offsets: &[u32], neighbours: &[u32]) -> Vec<u32> {
    let row = |p: usize| neighbour_offsets[p] as usize..neighbour_offsets[p + 1] as usize;
    let mut transpose = vec![u32::MAX; neighbours.len()];
    for c in 0..neighbour_offsets.len().saturating_sub(1) {
        for k in row(c) {
            let b = neighbours[k] as usize;
            if let Some(kb) = row(b).find(|&kb| neighbours[kb] as usize == c) {
                transpose[k] = kb as u32;
            }
        }
    }
    transpose
}

/// The pairs an activation's modes make carry a force, each once, and per particle of the
/// force set the pairs it owns and those it is the other end of. Built from the stress and
/// force lists it is used with; `valid` is false until the first build.
#[derive(Default, PartialEq)]
pub struct PairPlan {
    /// Per particle of the stress list, the start of its owned pairs in `slots`
    /// (stress-list length + 1 entries).
    owner_offsets: Vec<u32>,
    /// Per pair, its slot in its owner's neighbour list.
    slots: Vec<u32>,
    /// Per particle of the force list, its place in the stress list (`u32::MAX` outside S).
    owner_of: Vec<u32>,
    /// Per particle of the force list, the start of its entries in `incoming` (force-list
    /// length + 1 entries).
    incoming_offsets: Vec<u32>,
    /// The pairs a particle is the other end of (not the owner), in its neighbour-list order.
    incoming: Vec<u32>,
    /// Per pair, the force-list place of its other end (not the owner).
    other_place: Vec<u32>,
    /// Per particle of the stress list, its place in the force list.
    owner_place: Vec<u32>,
    /// The stress and force lists the plan was built from.
    built_for: (Vec<u32>, Vec<u32>),
    /// Built from the current lists and modes.
    pub valid: bool,
    /// This build's number (0 before the first), for [`PairScratch`]'s records.
    build: u64,
}

impl Clone for PairPlan {
    fn clone(&self) -> Self {
        let mut c = PairPlan::default();
        c.clone_from(self);
        c
    }

    /// Copies into the existing buffers (a checkpoint every batch allocates nothing).
    fn clone_from(&mut self, s: &Self) {
        self.owner_offsets.clone_from(&s.owner_offsets);
        self.slots.clone_from(&s.slots);
        self.owner_of.clone_from(&s.owner_of);
        self.incoming_offsets.clone_from(&s.incoming_offsets);
        self.incoming.clone_from(&s.incoming);
        self.other_place.clone_from(&s.other_place);
        self.owner_place.clone_from(&s.owner_place);
        self.built_for.0.clone_from(&s.built_for.0);
        self.built_for.1.clone_from(&s.built_for.1);
        self.valid = s.valid;
        self.build = s.build;
    }
}

impl PairPlan {
    /// Rebuild for the lists and modes an activation left (nothing to do when the stress and
    /// force lists are those of the last build: which pairs carry a force and who owns them
    /// depend only on S and F). `transpose` is [`transpose_slots`] of the lists;
    /// `scratch`'s contents do not matter. F must hold S and every neighbour of S, as the
    /// activation makes it; otherwise the plan is left invalid (the stepper then gathers).
    pub fn rebuild(
        &mut self,
        stress_list: &[u32],
        force_list: &[u32],
        modes: &[u32],
        (neighbour_offsets, neighbours, transpose): (&[u32], &[u32], &[u32]),
        scratch: &mut PlanScratch,
    ) {
        if self.valid && self.built_for.0 == stress_list && self.built_for.1 == force_list {
            return;
        }
        let PlanScratch {
            stress_place,
            force_place,
            row_start,
            row_pairs,
        } = scratch;
        stress_place.resize(modes.len(), 0);
        force_place.resize(modes.len(), 0);
        let in_s = |p: usize| modes[p] & mode::IN_S != 0;
        let row = |p: usize| neighbour_offsets[p] as usize..neighbour_offsets[p + 1] as usize;
        // Per particle of F, its neighbour row in a compact copy (`row_pairs`) where each
        // pair it does not own gets the pair's number: a small array in cache, written at
        // the pair's slot in that row (`transpose`), read back in row order.
        row_start.clear();
        row_start.push(0);
        for (j, &c) in force_list.iter().enumerate() {
            force_place[c as usize] = j as u32;
            row_start.push(row_start[j] + row(c as usize).len() as u32);
        }
        row_pairs.clear();
        row_pairs.resize(row_start[force_list.len()] as usize, u32::MAX);
        let in_force_list = |p: usize| {
            let j = force_place[p] as usize;
            j < force_list.len() && force_list[j] as usize == p
        };
        self.owner_offsets.clear();
        self.owner_offsets.push(0);
        // Ownership is decided without a branch (S's edge makes it unpredictable): every slot
        // is written, the count advances for an owned one, and b's row gets the pair's number
        // or "none". Every neighbour of S must be in the force list (else the plan is invalid).
        let bound: usize = stress_list.iter().map(|&c| row(c as usize).len()).sum();
        self.slots.clear();
        self.slots.resize(bound, 0);
        self.other_place.clear();
        self.other_place.resize(bound, 0);
        self.owner_place.clear();
        let mut n_pairs = 0usize;
        let mut neighbours_in_f = true;
        for (i, &c) in stress_list.iter().enumerate() {
            let c = c as usize;
            stress_place[c] = i as u32;
            neighbours_in_f &= in_force_list(c);
            self.owner_place.push(force_place[c]);
            for k in row(c) {
                // c (in S) owns (c, b) unless b is in S with a lower index.
                let b = neighbours[k] as usize;
                let owned = !in_s(b) || c < b;
                let b_in_f = in_force_list(b);
                neighbours_in_f &= b_in_f;
                if b_in_f {
                    let at = row_start[force_place[b] as usize] as usize + transpose[k] as usize
                        - neighbour_offsets[b] as usize;
                    row_pairs[at] = if owned { n_pairs as u32 } else { u32::MAX };
                }
                self.slots[n_pairs] = k as u32;
                self.other_place[n_pairs] = force_place[b];
                n_pairs += owned as usize;
            }
            self.owner_offsets.push(n_pairs as u32);
        }
        if !neighbours_in_f {
            // F is S and its neighbours (`mark_set`); lists that are not cannot be paired.
            self.valid = false;
            return;
        }
        self.slots.truncate(n_pairs);
        self.other_place.truncate(n_pairs);
        self.owner_of.clear();
        self.incoming_offsets.clear();
        self.incoming.clear();
        self.incoming_offsets.push(0);
        for (j, &c) in force_list.iter().enumerate() {
            let c = c as usize;
            self.owner_of
                .push(if in_s(c) { stress_place[c] } else { u32::MAX });
            let own_row = row_start[j] as usize..row_start[j + 1] as usize;
            let mut len = self.incoming.len();
            self.incoming.resize(len + own_row.len(), 0);
            for &e in &row_pairs[own_row] {
                self.incoming[len] = e;
                len += (e != u32::MAX) as usize;
            }
            self.incoming.truncate(len);
            self.incoming_offsets.push(len as u32);
        }
        self.built_for.0.clear();
        self.built_for.0.extend_from_slice(stress_list);
        self.built_for.1.clear();
        self.built_for.1.extend_from_slice(force_list);
        self.valid = true;
        self.build = NEXT_BUILD.fetch_add(1, Ordering::Relaxed);
    }

    /// Each pair's rest quantities, in pair order, into `records` (owner c, slot k,
    /// neighbour b: ∇W(X_b − X_c), X_cb, the hourglass weight h·W(r0)/r0² from `table` and b's
    /// force-list place), in parallel over the owners.
    fn write_records(
        &self,
        stress_list: &[u32],
        rest: &[f32],
        neighbours: &[u32],
        table: &PairTable,
        records: &mut Vec<PairRecord>,
    ) {
        use rayon::prelude::*;
        let blank = PairRecord {
            gradient: Vec3A::ZERO,
            x0cb: Vec3A::ZERO,
            other: 0,
            hourglass: 0.0,
        };
        records.clear();
        records.resize(self.slots.len(), blank);
        self.owner_runs(stress_list, records)
            .into_par_iter()
            .with_min_len(16)
            .for_each(|(c, first, run)| {
                let x0c = load3a(rest, c);
                let pairs = self.slots[first..].iter().zip(&self.other_place[first..]);
                for (r, (&k, &other)) in run.iter_mut().zip(pairs) {
                    let k = k as usize;
                    *r = PairRecord {
                        gradient: table.gradient[k].into(),
                        x0cb: x0c - load3a(rest, neighbours[k] as usize),
                        other,
                        hourglass: table.hourglass[k],
                    };
                }
            });
    }

    /// `per_pair` (one entry per pair) cut into its owners' runs: (owner, its first pair,
    /// its run), in stress-list order.
    fn owner_runs<'a, T>(
        &self,
        stress_list: &[u32],
        per_pair: &'a mut [T],
    ) -> Vec<(usize, usize, &'a mut [T])> {
        let mut runs = Vec::with_capacity(stress_list.len());
        let mut rest = per_pair;
        for (i, &c) in stress_list.iter().enumerate() {
            let n = (self.owner_offsets[i + 1] - self.owner_offsets[i]) as usize;
            let (run, after) = rest.split_at_mut(n);
            runs.push((c as usize, self.owner_offsets[i] as usize, run));
            rest = after;
        }
        runs
    }

    /// Number of pairs that carry a force.
    pub fn pairs(&self) -> usize {
        self.slots.len()
    }

    /// The force stage: per particle of `force_list` (the list the plan was built with),
    /// `particle_forces`, `particle_contact` and the sub-step sum (`accumulate`: add to it),
    /// as [`super::sph_forces::sph_forces`] writes them: f_c = Σ of its owned pairs' terms
    /// (slot order) − Σ of the terms of the pairs it is the other end of (slot order), then
    /// gravity and contact. A pair (c, b) adds V²(A_c + A_b)∇W(X_b − X_c) and, when c or b
    /// is dynamic, the hourglass term x_cb·w_h·((F_c + F_b)X_cb·x_cb / |x_cb|² − n_S), with
    /// A = 0, F = 0 outside S and n_S the pair's count of particles in S: the kernel's terms,
    /// computed from each particle's quantities packed once per step (`PairSide`).
    /// `scratch` holds them, the owners' sums, each pair's terms and each pair's rest
    /// quantities from `inp.pairs` (rewritten when the plan is another build's). tlsph with
    /// a pair table only (the paper model's one-sided terms are not antisymmetric): otherwise
    /// this is the gather [`super::sph_forces::sph_forces`].
    #[allow(clippy::too_many_arguments)]
    pub fn sph_forces(
        &self,
        inp: &ForceInputs,
        stress_list: &[u32],
        force_list: &[u32],
        accumulate: bool,
        scratch: &mut PairScratch,
        particle_forces: &mut [f32],
        particle_force_sum: &mut [f32],
        particle_contact: &mut [f32],
    ) {
        let (0, Some(table)) = (inp.pp.model, inp.pairs) else {
            super::sph_forces::sph_forces(
                inp,
                force_list,
                accumulate,
                particle_forces,
                particle_force_sum,
                particle_contact,
            );
            return;
        };
        let mut results = std::mem::take(&mut scratch.results);
        self.pair_sums(
            inp,
            (stress_list, force_list, table),
            scratch,
            &mut results,
            |c, side, fa: Vec3A| {
                let mut f = Vec3::from(fa);
                let contact = if inp.mode[c] & mode::DYNAMIC != 0 {
                    // A dynamic particle is in S (the activation marks S from them), so its
                    // packed F is I + H, not the 0 of particles outside S.
                    debug_assert!(
                        inp.mode[c] & mode::IN_S != 0,
                        "dynamic particle {c} not in S"
                    );
                    add_external(inp, c, (side.u, side.f), &mut f)
                } else {
                    Vec3::ZERO
                };
                (f, contact)
            },
        );
        scratch.results = results;
        let results = &scratch.results;
        store_forces(
            inp,
            force_list,
            results,
            accumulate,
            particle_forces,
            particle_force_sum,
            particle_contact,
        );
    }
}

impl PairPlan {
    /// Per particle c of `force_list` (its place i), `finish(c, its packed side, the sum of
    /// its pairs' terms)` into `out` (force-list order): the sum is Σ of its owned pairs'
    /// terms (slot order) − Σ of the terms of the pairs it is the other end of (slot order),
    /// each term [`PairSum::of`] the pair's stress and hourglass parts ([`PairPlan::sph_forces`]
    /// says which).
    fn pair_sums<T: PairSum, R: Send>(
        &self,
        inp: &ForceInputs,
        (stress_list, force_list, table): (&[u32], &[u32], &PairTable),
        scratch: &mut PairScratch<T>,
        out: &mut Vec<R>,
        finish: impl Fn(usize, &PairSide, T) -> R + Sync + Send,
    ) {
        use rayon::prelude::*;
        let PairScratch {
            owned_sum,
            terms,
            sides,
            records,
            records_build,
            ..
        } = scratch;
        if *records_build != self.build {
            self.write_records(stress_list, inp.rest, inp.neighbours, table, records);
            *records_build = self.build;
        }
        let records = &records[..];
        PairSide::pack(inp, force_list, sides);
        let sides = &sides[..];
        owned_sum.resize(stress_list.len(), T::default());
        terms.resize(self.slots.len(), T::default());
        // Each owner's pairs are a contiguous run: hand each owner its run and its sum.
        self.owner_runs(stress_list, terms)
            .into_par_iter()
            .zip(owned_sum.par_iter_mut())
            .zip(self.owner_place.par_iter())
            .map(|(((_, first, run), sum), &place)| (first, run, sum, place))
            .with_min_len(16)
            .for_each(|(first, run, sum, place)| {
                let c = &sides[place as usize];
                let mut fa = T::default();
                for (out, r) in run.iter_mut().zip(&records[first..]) {
                    *out = pair_term(c, &sides[r.other as usize], r);
                    fa += *out;
                }
                *sum = fa;
            });
        let (terms, owned_sum) = (&terms[..], &owned_sum[..]);
        force_list
            .par_iter()
            .enumerate()
            .with_min_len(16)
            .map(|(i, &c)| {
                let mut fa = match self.owner_of[i] {
                    u32::MAX => T::default(),
                    o => owned_sum[o as usize],
                };
                let range =
                    self.incoming_offsets[i] as usize..self.incoming_offsets[i + 1] as usize;
                for &e in &self.incoming[range] {
                    fa -= terms[e as usize];
                }
                finish(c as usize, &sides[i], fa)
            })
            .collect_into_vec(out);
    }

    /// Design 8's force stage with each pair once (the twin it equals to rounding:
    /// [`super::exact_stages::exact_forces`]): per particle c of `force_list` (the plan's),
    /// its pair part P_c (the pairs' V²(A_c + A_b)∇W) and hourglass part H_c apart; a dynamic
    /// particle gets P_c + H_c, gravity and the tool's contact (`forces`, `contact`) and its
    /// hosts −P_c (`host_force`); a follower gets H_c, no contact, and its hosts H_c. tlsph with
    /// a pair table only (the caller gathers otherwise).
    pub fn exact_forces(
        &self,
        inp: &ForceInputs,
        (stress_list, force_list, table): (&[u32], &[u32], &PairTable),
        scratch: &mut PairScratch<Split>,
        forces: &mut [f32],
        contact: &mut [f32],
        host_force: &mut [f32],
    ) {
        let mut results = std::mem::take(&mut scratch.split_results);
        self.pair_sums(
            inp,
            (stress_list, force_list, table),
            scratch,
            &mut results,
            |c, side, s: Split| {
                if inp.mode[c] & mode::DYNAMIC != 0 {
                    let mut f = Vec3::from(s.pair + s.hourglass);
                    let touch = add_external(inp, c, (side.u, side.f), &mut f);
                    (f, touch, -Vec3::from(s.pair))
                } else {
                    let h = Vec3::from(s.hourglass);
                    (h, Vec3::ZERO, h)
                }
            },
        );
        for (&c, &(f, touch, host)) in force_list.iter().zip(&results) {
            let c = c as usize;
            super::store3(forces, c, f);
            super::store3(contact, c, touch);
            super::store3(host_force, c, host);
        }
        scratch.split_results = results;
    }
}

/// What a pair's term adds to its owner's sum (the other end subtracts it): the energy
/// blend's whole term ([`Vec3A`]), or design 8's two parts apart ([`Split`]).
pub trait PairSum:
    Copy + Default + Send + Sync + std::ops::AddAssign + std::ops::SubAssign
{
    /// The term of a pair from its stress part and its hourglass part (absent: zero).
    fn of(stress: Vec3A, hourglass: Option<Vec3A>) -> Self;
}

impl PairSum for Vec3A {
    /// stress + hourglass.
    #[inline]
    fn of(stress: Vec3A, hourglass: Option<Vec3A>) -> Self {
        match hourglass {
            Some(h) => stress + h,
            None => stress,
        }
    }
}

/// A pair's stress part (`pair`) and hourglass part apart (design 8 passes only minus the
/// first to a dynamic particle's hosts).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Split {
    /// V²(A_c + A_b)∇W(X_b − X_c).
    pub pair: Vec3A,
    /// The hourglass term (zero where it does not apply).
    pub hourglass: Vec3A,
}

impl std::ops::AddAssign for Split {
    fn add_assign(&mut self, o: Split) {
        self.pair += o.pair;
        self.hourglass += o.hourglass;
    }
}

impl std::ops::SubAssign for Split {
    fn sub_assign(&mut self, o: Split) {
        self.pair -= o.pair;
        self.hourglass -= o.hourglass;
    }
}

impl PairSum for Split {
    #[inline]
    fn of(stress: Vec3A, hourglass: Option<Vec3A>) -> Self {
        Split {
            pair: stress,
            hourglass: hourglass.unwrap_or(Vec3A::ZERO),
        }
    }
}

/// The force on owner c from its pair with b (record `r`): see [`PairPlan::sph_forces`].
/// The hourglass term only where it applies (c or b dynamic; |x_cb| > 0, which the kernel
/// also asks; its other test, r0 > 0, is in the record: the weight is 0 where r0 = 0).
#[inline]
fn pair_term<T: PairSum>(c: &PairSide, b: &PairSide, r: &PairRecord) -> T {
    let stress = (c.a + b.a) * r.gradient;
    if c.dynamic + b.dynamic == 0.0 {
        return T::of(stress, None);
    }
    let xcb = r.x0cb + c.u - b.u;
    let r2 = xcb.length_squared();
    if r2 > 0.0 {
        let g = (c.f + b.f) * r.x0cb;
        T::of(
            stress,
            Some(xcb * (r.hourglass * (g.dot(xcb) / r2 - (c.in_s + b.in_s)))),
        )
    } else {
        T::of(stress, None)
    }
}

/// One force-list particle's quantities as the pair loop reads them, packed once per step
/// in an aligned 128-byte record (one load per matrix column): V²A and F = I + H (both 0
/// outside S), its displacement, and whether it is in S and dynamic (1 or 0).
#[derive(Clone, Copy)]
struct PairSide {
    a: Mat3A,
    f: Mat3A,
    u: Vec3A,
    in_s: f32,
    dynamic: f32,
}

impl PairSide {
    /// Pack every particle of `force_list` into `sides` (force-list order), in parallel.
    fn pack(inp: &ForceInputs, force_list: &[u32], sides: &mut Vec<PairSide>) {
        use rayon::prelude::*;
        let blank = PairSide {
            a: Mat3A::ZERO,
            f: Mat3A::ZERO,
            u: Vec3A::ZERO,
            in_s: 0.0,
            dynamic: 0.0,
        };
        sides.resize(force_list.len(), blank);
        let v2 = inp.pp.volume * inp.pp.volume;
        sides
            .par_iter_mut()
            .zip(force_list.par_iter())
            .with_min_len(64)
            .for_each(|(side, &c)| {
                let c = c as usize;
                let m = inp.mode[c];
                let in_s = m & mode::IN_S != 0;
                *side = PairSide {
                    a: if in_s {
                        load_mat3a(inp.stress, c) * v2
                    } else {
                        Mat3A::ZERO
                    },
                    f: if in_s {
                        Mat3A::IDENTITY + load_mat3a(inp.gradient, c)
                    } else {
                        Mat3A::ZERO
                    },
                    u: load3a(inp.displacements, c),
                    in_s: in_s as u32 as f32,
                    dynamic: (m & mode::DYNAMIC != 0) as u32 as f32,
                };
            });
    }
}

/// Scratch of [`PairPlan::rebuild`] (not part of a checkpoint).
#[derive(Default)]
pub struct PlanScratch {
    /// Per particle in S, its place in the stress list.
    stress_place: Vec<u32>,
    /// Per particle in F, its place in the force list.
    force_place: Vec<u32>,
    /// Per particle of the force list, the start of its row in `row_pairs` (+ the end).
    row_start: Vec<u32>,
    /// Per force-list particle's neighbour slot, the pair it is the other end of there
    /// (`u32::MAX`: none).
    row_pairs: Vec<u32>,
}

/// Per-step scratch of [`PairPlan::sph_forces`] (`T` = [`Vec3A`]) and
/// [`PairPlan::exact_forces`] (`T` = [`Split`]); not part of a checkpoint.
#[derive(Default)]
pub struct PairScratch<T = Vec3A> {
    /// Per owner (stress-list order), the sum of its owned pairs' terms.
    owned_sum: Vec<T>,
    /// Per pair, the force on its owner.
    terms: Vec<T>,
    /// Per particle of the force list, its packed quantities this step.
    sides: Vec<PairSide>,
    /// Per particle of the force list, its force and contact force this step.
    results: Vec<(Vec3, Vec3)>,
    /// Design 8's per force-list particle: its force, contact force and its hosts' force.
    split_results: Vec<(Vec3, Vec3, Vec3)>,
    /// Per pair, its rest quantities (read in order instead of through the slots).
    records: Vec<PairRecord>,
    /// The plan build `records` belong to (0: none).
    records_build: u64,
}

/// One pair's rest quantities, as the pair loop reads them.
#[derive(Clone, Copy)]
struct PairRecord {
    /// ∇W(X_b − X_c).
    gradient: Vec3A,
    /// X_c − X_b.
    x0cb: Vec3A,
    /// The other particle's place in the force list.
    other: u32,
    /// h·W(r0)/r0².
    hourglass: f32,
}
