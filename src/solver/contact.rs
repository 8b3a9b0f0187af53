//! The active contact set of a projected solve: which contacts hold their vertex, and the residual and direction restricted to their tangent space.

use glam::Vec3;

use super::ActiveContact;
use super::kernels::Sums;

/// One vertex held by at least one contact: the orthonormal basis of its held contact normals.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Held {
    vertex: u32,
    /// Bit `k`: the vertex's `k`-th contact entry is held.
    mask: u32,
    /// Orthonormalised held normals (`count` of them).
    basis: [Vec3; 3],
    count: u32,
    /// Friction sticks the vertex: every force component is taken by the contact.
    stick: bool,
}

impl Held {
    /// `v` without its components along the held normals (zero when stuck).
    #[inline]
    fn tangent(&self, v: Vec3) -> Vec3 {
        if self.stick {
            return Vec3::ZERO;
        }
        let mut t = v;
        for b in &self.basis[..self.count as usize] {
            t -= *b * t.dot(*b);
        }
        t
    }
}

/// `Γ` of the proportioning test in [`ContactSet::constrain`]: held contacts that pull away are
/// released when their (preconditioned) force exceeds `Γ` times the free residual. 1 is
/// MPRGP's usual choice; 0.5 and 2 ran about as well on the bench's arm.
pub(crate) const PROPORTIONING: f64 = 1.0;

/// What [`ContactSet::constrain`] changed.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct Constrained {
    /// A contact is held that was not at the previous call (the caller restarts its
    /// directions only in a solve's first iterations; later it keeps them, projected onto
    /// the new contact's tangent plane).
    pub new_hold: bool,
    /// The pulling contacts were released (a proportioning step).
    pub released: bool,
    /// `Σ β²`: the squared outward forces of the held contacts that pull away, N².
    pub chopped_rr: f64,
}

/// The held set [`ContactSet::decide`] chose, with its corrections to the sums.
#[derive(Debug, Clone, Copy, Default)]
struct Decision {
    new_hold: bool,
    released: bool,
    delta_rr: f64,
    delta_rzr: f64,
    chopped_rr: f64,
    chopped_rzr: f64,
}

/// The contacts a projection reported and the ones the solver holds.
#[derive(Debug, Default)]
pub(crate) struct ContactSet {
    list: Vec<ActiveContact>,
    /// One flag per entry of `list`: held.
    pub held_flags: Vec<bool>,
    held: Vec<Held>,
    /// `(vertex, mask)` of the held vertices in the previous iteration.
    previous: Vec<(u32, u32)>,
    /// The vertices that lost a held contact in the last proportioning release.
    released: Vec<u32>,
}

impl ContactSet {
    /// Takes the projection's active contacts (sorted by vertex).
    pub fn refresh(&mut self, contacts: &[ActiveContact]) {
        self.list.clear();
        self.list.extend_from_slice(contacts);
    }

    /// `Σ r·d` over the vertices of the reported contacts (each once): the part of a sum over
    /// all vertices that [`constrain`](Self::constrain) can change.
    pub fn dot_at_contacts(&self, r: &[Vec3], d: &[Vec3]) -> f64 {
        let mut sum = 0.0;
        let mut last = None;
        for c in &self.list {
            if last != Some(c.vertex) {
                let v = c.vertex as usize;
                sum += f64::from(r[v].dot(d[v]));
                last = Some(c.vertex);
            }
        }
        sum
    }

    /// Decides which contacts hold their vertex, drops the held normal components from `r`
    /// (all of `r` for a sticking contact) and corrects the sums `rr` and `rzr` of the force
    /// gather for them.
    ///
    /// A contact whose net force `r` pushes into the collider (`r · n < 0`) is held. A contact
    /// held at the previous call stays held even when its force now pulls it away: its
    /// outward force `β` is then the *chopped* residual, which leaves `r` but is reported
    /// apart (the convergence test counts it). Only when the chopped residual outweighs the
    /// free one (`Σ w β² > Γ² Σ w r²`, [`PROPORTIONING`] `= Γ`) are all the pulling contacts
    /// released at once: a proportioning step, as in Dostál's MPRGP. The caller then steps
    /// along the released vertices' forces only
    /// ([`proportioning_direction`](Self::proportioning_direction)) and restarts the
    /// directions after it. Releasing each contact as soon as its force turned (the old
    /// policy) let the contacts at the rim of a patch, whose normal force is near zero, be
    /// held and released every other iteration.
    pub fn constrain(&mut self, r: &mut [Vec3], w: &[f32], sums: &mut Sums) -> Constrained {
        let mut previous = std::mem::take(&mut self.previous);
        previous.clear();
        previous.extend(self.held.iter().map(|h| (h.vertex, h.mask)));
        let mut out = self.decide(r, w, &previous, false);
        let free_rzr = (sums.rzr + out.delta_rzr).max(0.0);
        if out.chopped_rzr > PROPORTIONING * PROPORTIONING * free_rzr {
            out = self.decide(r, w, &previous, true);
            out.released = true;
        }
        for h in &self.held {
            let v = &mut r[h.vertex as usize];
            *v = h.tangent(*v);
        }
        sums.rr = (sums.rr + out.delta_rr).max(0.0);
        sums.rzr = (sums.rzr + out.delta_rzr).max(0.0);
        self.previous = previous;
        Constrained {
            new_hold: out.new_hold,
            released: out.released,
            chopped_rr: out.chopped_rr,
        }
    }

    /// The held set for the force `r` (see [`constrain`](Self::constrain)); `release`: hold
    /// only the contacts pushed in.
    fn decide(
        &mut self,
        r: &[Vec3],
        w: &[f32],
        previous: &[(u32, u32)],
        release: bool,
    ) -> Decision {
        let mut out = Decision::default();
        self.released.clear();
        self.held.clear();
        self.held_flags.clear();
        self.held_flags.resize(self.list.len(), false);
        let mut k = 0;
        while k < self.list.len() {
            let vertex = self.list[k].vertex;
            let end = k + self.list[k..]
                .iter()
                .take_while(|c| c.vertex == vertex)
                .count();
            let Some(&f) = r.get(vertex as usize) else {
                k = end;
                continue;
            };
            let prev_mask = previous
                .binary_search_by_key(&vertex, |p| p.0)
                .map_or(0, |i| previous[i].1);
            let before = if release { 0 } else { prev_mask };
            let mut held = Held {
                vertex,
                mask: 0,
                basis: [Vec3::ZERO; 3],
                count: 0,
                stick: false,
            };
            let mut chopped = 0.0f32;
            for (j, c) in self.list[k..end].iter().enumerate() {
                let bit = 1 << j.min(31);
                let push = f.dot(c.normal);
                if push >= 0.0 {
                    if before & bit == 0 {
                        continue;
                    }
                    chopped += push * push;
                }
                self.held_flags[k + j] = true;
                held.mask |= bit;
                held.stick |= c.stick;
                if held.count < 3 {
                    let mut n = c.normal;
                    for b in &held.basis[..held.count as usize] {
                        n -= *b * n.dot(*b);
                    }
                    let len = n.length();
                    if len > 1e-3 {
                        held.basis[held.count as usize] = n / len;
                        held.count += 1;
                    }
                }
            }
            if release && prev_mask & !held.mask != 0 {
                self.released.push(vertex);
            }
            if held.mask != 0 {
                let g = held.tangent(f);
                let wi = w[vertex as usize];
                let (ff, gg) = (f.dot(f), g.dot(g));
                out.delta_rr += gg as f64 - ff as f64;
                out.delta_rzr += (wi * gg) as f64 - (wi * ff) as f64;
                out.chopped_rr += chopped as f64;
                out.chopped_rzr += (wi * chopped) as f64;
                out.new_hold |= prev_mask & held.mask != held.mask;
                self.held.push(held);
            }
            k = end;
        }
        out
    }

    /// The proportioning step's direction after a release: `d = w r` at the released vertices
    /// (their remaining held normals projected out), zero elsewhere; returns the slope `Σ r·d`.
    ///
    /// Only the released vertices move, as in MPRGP's proportioning step (a step along the
    /// chopped gradient), and the line search sizes the step for them alone. A restart along
    /// the whole preconditioned residual instead moves them by the step the rest of the mesh
    /// wants.
    pub fn proportioning_direction(&self, d: &mut [Vec3], r: &[Vec3], w: &[f32]) -> f64 {
        d.fill(Vec3::ZERO);
        let mut slope = 0.0f64;
        for &v in &self.released {
            let i = v as usize;
            let mut z = r[i] * w[i].max(0.0);
            if let Ok(h) = self.held.binary_search_by_key(&v, |h| h.vertex) {
                z = self.held[h].tangent(z);
            }
            d[i] = z;
            slope += f64::from(r[i].dot(z));
        }
        slope
    }

    /// Re-applies the held set's projection to a force `r` gathered again at the same point.
    pub fn reapply(&self, r: &mut [Vec3]) {
        for h in &self.held {
            let v = &mut r[h.vertex as usize];
            *v = h.tangent(*v);
        }
    }

    /// Drops the held normal components from the search direction `d` (all of it for a
    /// sticking contact); returns the change of the slope `Σ r·d`.
    pub fn constrain_direction(&self, d: &mut [Vec3], r: &[Vec3]) -> f64 {
        let mut delta = 0.0f64;
        for h in &self.held {
            let i = h.vertex as usize;
            let t = h.tangent(d[i]);
            delta += r[i].dot(t) as f64 - r[i].dot(d[i]) as f64;
            d[i] = t;
        }
        delta
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn contact(vertex: u32) -> ActiveContact {
        ActiveContact {
            vertex,
            normal: Vec3::Z,
            stick: false,
        }
    }

    fn sums(r: &[Vec3]) -> Sums {
        let rr: f64 = r.iter().map(|v| f64::from(v.length_squared())).sum();
        Sums {
            rr,
            rzr: rr,
            ..Sums::default()
        }
    }

    /// A contact held once stays held while its force turns to pull it off only slightly (the
    /// pull is reported as chopped residual, not released), and is released by a
    /// proportioning step once that pull outweighs the rest of the residual.
    #[test]
    fn a_held_contact_is_released_only_when_its_pull_dominates() {
        let mut set = ContactSet::default();
        set.refresh(&[contact(0)]);
        let w = [1.0, 1.0];
        // Pushed into the collider: held, its normal force leaves the residual.
        let mut r = vec![Vec3::new(0.5, 0.0, -1.0), Vec3::new(1.0, 0.0, 0.0)];
        let mut s = sums(&r);
        let c = set.constrain(&mut r, &w, &mut s);
        assert!(c.new_hold && !c.released && set.held_flags == [true]);
        assert_eq!(r[0], Vec3::new(0.5, 0.0, 0.0));
        assert!((s.rr - 1.25).abs() < 1e-12 && c.chopped_rr == 0.0);

        // Now pulled off by 0.1 N while 1 N acts elsewhere: still held (the old policy
        // released it here and held it again at the next push, restarting each time).
        let mut r = vec![Vec3::new(0.0, 0.0, 0.1), Vec3::new(1.0, 0.0, 0.0)];
        let mut s = sums(&r);
        let c = set.constrain(&mut r, &w, &mut s);
        assert!(!c.new_hold && !c.released && set.held_flags == [true]);
        assert_eq!(r[0], Vec3::ZERO);
        assert!((c.chopped_rr - 0.01).abs() < 1e-9, "{}", c.chopped_rr);
        assert!((s.rr - 1.0).abs() < 1e-9);

        // The rest of the residual has gone: the pull dominates and the contact is released.
        let mut r = vec![Vec3::new(0.0, 0.0, 0.1), Vec3::new(0.01, 0.0, 0.0)];
        let mut s = sums(&r);
        let c = set.constrain(&mut r, &w, &mut s);
        assert!(c.released && !c.new_hold && set.held_flags == [false]);
        assert_eq!(r[0], Vec3::new(0.0, 0.0, 0.1));
        assert_eq!(c.chopped_rr, 0.0);
        assert!((s.rr - (0.01 + 1e-4)).abs() < 1e-9);

        // The proportioning step moves the released vertex alone, along its preconditioned
        // force: d = w r there, zero elsewhere, slope Σ w r².
        let mut d = vec![Vec3::ONE; 2];
        let slope = set.proportioning_direction(&mut d, &r, &[0.5, 1.0]);
        assert_eq!(d, [Vec3::new(0.0, 0.0, 0.05), Vec3::ZERO]);
        assert!((slope - 0.005).abs() < 1e-9, "{slope}");

        // A contact never held is not held by a pull.
        let mut r = vec![Vec3::new(0.0, 0.0, 0.1), Vec3::new(1.0, 0.0, 0.0)];
        let mut s = sums(&r);
        let c = set.constrain(&mut r, &w, &mut s);
        assert!(!c.new_hold && !c.released && set.held_flags == [false]);
    }
}
