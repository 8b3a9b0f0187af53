//! Closed test and benchmark surfaces: latitude-longitude ellipsoids, wound outwards.

use glam::Vec3;

/// A closed latitude–longitude ellipsoid around `centre` with semi-axes `radii_m`: `n_lat` bands
/// (≥ 2) between the poles, `n_lon` (≥ 3) vertices per ring. Triangles wind counter-clockwise
/// seen from outside; there are `2 n_lon (n_lat − 1)` of them. Returns `None` for too few
/// bands or sectors.
///
/// ```
/// use dermis::collision::{ColliderMesh, shapes::ellipsoid};
/// use glam::Vec3;
/// let (v, t) = ellipsoid(Vec3::ZERO, Vec3::ONE, 8, 12).unwrap();
/// assert_eq!(t.len(), 2 * 12 * 7);
/// assert!(ColliderMesh::from_mesh(v, t).is_ok());
/// ```
pub fn ellipsoid(
    centre: Vec3,
    radii_m: Vec3,
    n_lat: u32,
    n_lon: u32,
) -> Option<(Vec<Vec3>, Vec<[u32; 3]>)> {
    if n_lat < 2 || n_lon < 3 {
        return None;
    }
    let mut v = vec![centre + Vec3::new(0.0, 0.0, radii_m.z)];
    for j in 1..n_lat {
        let theta = std::f32::consts::PI * j as f32 / n_lat as f32;
        for i in 0..n_lon {
            let phi = std::f32::consts::TAU * i as f32 / n_lon as f32;
            let unit = Vec3::new(
                theta.sin() * phi.cos(),
                theta.sin() * phi.sin(),
                theta.cos(),
            );
            v.push(centre + unit * radii_m);
        }
    }
    v.push(centre - Vec3::new(0.0, 0.0, radii_m.z));
    let south = v.len() as u32 - 1;
    let ring = |j: u32, i: u32| 1 + (j - 1) * n_lon + i % n_lon;
    let mut t = Vec::with_capacity((2 * n_lon * (n_lat - 1)) as usize);
    for i in 0..n_lon {
        t.push([0, ring(1, i), ring(1, i + 1)]);
    }
    for j in 1..n_lat - 1 {
        for i in 0..n_lon {
            let (a0, a1, b0, b1) = (
                ring(j, i),
                ring(j, i + 1),
                ring(j + 1, i),
                ring(j + 1, i + 1),
            );
            t.push([a0, b0, b1]);
            t.push([a0, b1, a1]);
        }
    }
    for i in 0..n_lon {
        t.push([ring(n_lat - 1, i), south, ring(n_lat - 1, i + 1)]);
    }
    Some((v, t))
}
