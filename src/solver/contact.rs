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

/// The contacts a projection reported and the ones the solver holds.
#[derive(Debug, Default)]
pub(crate) struct ContactSet {
    list: Vec<ActiveContact>,
    /// One flag per entry of `list`: held.
    pub held_flags: Vec<bool>,
    held: Vec<Held>,
    /// `(vertex, mask)` of the held vertices in the previous iteration.
    previous: Vec<(u32, u32)>,
}

impl ContactSet {
    /// Takes the projection's active contacts (sorted by vertex).
    pub fn refresh(&mut self, contacts: &[ActiveContact]) {
        self.list.clear();
        self.list.extend_from_slice(contacts);
    }

    /// Decides which contacts hold their vertex (net force `r` pushing into the collider, i.e.
    /// `r · n < 0`; the others are released), drops the held normal components from `r` (all of
    /// `r` for a sticking contact) and corrects the sums `rr` and `rzr` of the force gather for
    /// them. Returns `true` when a contact is held that was not held at the previous call (the
    /// conjugate directions must restart).
    pub fn constrain(&mut self, r: &mut [Vec3], w: &[f32], sums: &mut Sums) -> bool {
        let mut previous = std::mem::take(&mut self.previous);
        previous.clear();
        previous.extend(self.held.iter().map(|h| (h.vertex, h.mask)));
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
            let mut held = Held {
                vertex,
                mask: 0,
                basis: [Vec3::ZERO; 3],
                count: 0,
                stick: false,
            };
            for (j, c) in self.list[k..end].iter().enumerate() {
                if f.dot(c.normal) >= 0.0 {
                    continue;
                }
                self.held_flags[k + j] = true;
                held.mask |= 1 << j.min(31);
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
            if held.mask != 0 {
                let g = held.tangent(f);
                let wi = w[vertex as usize];
                let (ff, gg) = (f.dot(f), g.dot(g));
                sums.rr += gg as f64 - ff as f64;
                sums.rzr += (wi * gg) as f64 - (wi * ff) as f64;
                r[vertex as usize] = g;
                self.held.push(held);
            }
            k = end;
        }
        sums.rr = sums.rr.max(0.0);
        sums.rzr = sums.rzr.max(0.0);
        // A vertex newly held loses the normal part of the old direction, whose conjugacy
        // then means nothing: restart. A released one only gains freedom (its normal force
        // enters through the residual): keep the direction. Restarting on releases too makes
        // the contacts at the rim of a contact patch, whose normal force is near zero,
        // restart the solve over and over (a draped sheet then stalls at 2e-3 instead of
        // converging).
        let changed = self.held.iter().any(|h| {
            previous
                .binary_search_by_key(&h.vertex, |p| p.0)
                .map_or(true, |k| previous[k].1 & h.mask != h.mask)
        });
        self.previous = previous;
        changed
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
