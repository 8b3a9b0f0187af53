//! Vertex renumbering for memory locality.

use glam::Vec3;

/// A permutation of the vertices along a Morton (Z-order) curve of their positions:
/// `order[i]` is the original index of the `i`-th vertex in the new order.
///
/// Neighbouring vertices end up close in memory, so the gather over springs stays in cache. Ties
/// (and non-finite positions) keep their original relative order, so the result is deterministic.
///
/// ```
/// use dermis::solver::morton_order;
/// use glam::Vec3;
/// let p = [Vec3::new(1.0, 1.0, 0.0), Vec3::ZERO, Vec3::new(1.0, 0.0, 0.0)];
/// assert_eq!(morton_order(&p), vec![1, 2, 0]);
/// ```
pub fn morton_order(positions: &[Vec3]) -> Vec<u32> {
    let finite = positions.iter().filter(|p| p.is_finite());
    let (lo, hi) = finite.fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), p| {
        (lo.min(*p), hi.max(*p))
    });
    let extent = (hi - lo).max_element();
    let scale = if extent > 0.0 {
        2_097_151.0 / extent
    } else {
        0.0
    };
    let mut keyed: Vec<(u64, u32)> = positions
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let q = ((*p - lo) * scale).clamp(Vec3::ZERO, Vec3::splat(2_097_151.0));
            let code = if p.is_finite() {
                spread(q.x as u64) | (spread(q.y as u64) << 1) | (spread(q.z as u64) << 2)
            } else {
                u64::MAX
            };
            (code, i as u32)
        })
        .collect();
    keyed.sort_unstable();
    keyed.into_iter().map(|(_, i)| i).collect()
}

/// Spreads the low 21 bits of `v` to every third bit.
fn spread(v: u64) -> u64 {
    let mut x = v & 0x1f_ffff;
    x = (x | (x << 32)) & 0x1f00000000ffff;
    x = (x | (x << 16)) & 0x1f0000ff0000ff;
    x = (x | (x << 8)) & 0x100f00f00f00f00f;
    x = (x | (x << 4)) & 0x10c30c30c30c30c3;
    x = (x | (x << 2)) & 0x1249249249249249;
    x
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn is_a_permutation_and_groups_neighbours() {
        // A 16x16 grid listed in a scrambled order.
        let mut p = Vec::new();
        for k in 0..256u32 {
            let s = (k * 97) % 256;
            p.push(Vec3::new((s % 16) as f32, (s / 16) as f32, 0.0));
        }
        let order = morton_order(&p);
        let mut seen = order.clone();
        seen.sort_unstable();
        assert_eq!(seen, (0..256).collect::<Vec<_>>());
        // Consecutive vertices in Morton order are close on average (a random order averages ~7).
        let mean: f32 = order
            .windows(2)
            .map(|w| p[w[0] as usize].distance(p[w[1] as usize]))
            .sum::<f32>()
            / 255.0;
        assert!(mean < 2.0, "mean step {mean}");
        assert_eq!(spread(0b111), 0b1001001);
    }
}
