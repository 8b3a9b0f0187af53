//! Animation clips: channels of keyframed samplers and their evaluation at a time.

use glam::{Mat4, Quat, Vec3, Vec4};
use serde::Serialize;

use super::{AnimationError, LocalTransform, Pose};

/// Translation, rotation and scale of a node, composed as `T * R * S`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Trs {
    /// Translation, metres.
    pub translation: Vec3,
    /// Rotation (unit quaternion).
    pub rotation: Quat,
    /// Scale per axis.
    pub scale: Vec3,
}

impl Trs {
    /// No translation, rotation or scale.
    pub const IDENTITY: Self = Self {
        translation: Vec3::ZERO,
        rotation: Quat::IDENTITY,
        scale: Vec3::ONE,
    };

    /// `T * R * S` as a matrix.
    pub fn to_mat4(&self) -> Mat4 {
        Mat4::from_scale_rotation_translation(self.scale, self.rotation, self.translation)
    }
}

/// How values between keyframes are computed (glTF `sampler.interpolation`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum Interpolation {
    /// Hold the previous key's value.
    Step,
    /// Linear interpolation; rotations use spherical linear interpolation on the short path.
    Linear,
    /// Cubic Hermite spline with an in-tangent, value and out-tangent per key.
    CubicSpline,
}

/// Keyframe values of one sampler. For [`Interpolation::CubicSpline`] every key holds three
/// consecutive entries: in-tangent, value, out-tangent.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub enum Keyframes {
    /// Node translations, metres.
    Translation(Vec<Vec3>),
    /// Node rotations (quaternions; normalised after interpolation).
    Rotation(Vec<Quat>),
    /// Node scales.
    Scale(Vec<Vec3>),
    /// Morph-target weights, `targets` consecutive values per entry.
    Weights {
        /// Number of morph targets (weights per entry).
        targets: usize,
        /// All weights, entry-major.
        values: Vec<f32>,
    },
}

impl Keyframes {
    /// Number of entries (a weights entry is one vector of `targets` weights).
    pub fn len(&self) -> usize {
        match self {
            Self::Translation(v) | Self::Scale(v) => v.len(),
            Self::Rotation(v) => v.len(),
            Self::Weights { targets, values } => {
                if *targets == 0 {
                    0
                } else {
                    values.len() / targets
                }
            }
        }
    }

    /// True when there are no entries.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    fn entry_count_exact(&self) -> bool {
        match self {
            Self::Weights { targets, values } => *targets == 0 || values.len() % targets == 0,
            _ => true,
        }
    }
}

/// Keyframe times and values with an interpolation mode.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Sampler {
    /// Interpolation mode.
    pub interpolation: Interpolation,
    /// Key times, seconds, strictly increasing.
    times: Vec<f32>,
    /// Key values.
    values: Keyframes,
}

/// The sampled value of a channel.
#[derive(Debug, Clone, PartialEq)]
enum Sampled {
    Translation(Vec3),
    Rotation(Quat),
    Scale(Vec3),
    Weights(Vec<f32>),
}

impl Sampler {
    /// Builds a sampler, checking that times are finite and strictly increasing and that the
    /// value count matches (one entry per key, three for CUBICSPLINE).
    pub fn new(
        interpolation: Interpolation,
        times: Vec<f32>,
        values: Keyframes,
    ) -> Result<Self, AnimationError> {
        if times.is_empty() {
            return Err(AnimationError::NoKeyframes);
        }
        for (key, &time) in times.iter().enumerate() {
            if !time.is_finite() || (key > 0 && time <= times[key - 1]) {
                return Err(AnimationError::UnsortedKeyframes { key, time });
            }
        }
        let per_key = if interpolation == Interpolation::CubicSpline {
            3
        } else {
            1
        };
        let (outputs, scale) = match &values {
            Keyframes::Weights { targets, values } => (values.len(), *targets),
            other => (other.len(), 1),
        };
        let expected = times.len() * per_key * scale;
        if outputs != expected || !values.entry_count_exact() {
            return Err(AnimationError::SamplerCountMismatch {
                inputs: times.len(),
                expected,
                outputs,
            });
        }
        Ok(Self {
            interpolation,
            times,
            values,
        })
    }

    /// Key times, seconds.
    pub fn times(&self) -> &[f32] {
        &self.times
    }

    /// Key values.
    pub fn values(&self) -> &Keyframes {
        &self.values
    }

    /// Time of the last key, seconds.
    pub fn end_time(&self) -> f32 {
        self.times.last().copied().unwrap_or(0.0)
    }

    /// Finds the segment `[k, k+1]` holding `t` and the normalised position in it. Times before
    /// the first key or after the last clamp to that key (`s = 0`, `k1 == k0`).
    fn segment(&self, t: f32) -> (usize, usize, f32, f32) {
        let n = self.times.len();
        if n == 1 || t <= self.times[0] || t.is_nan() {
            return (0, 0, 0.0, 0.0);
        }
        if t >= self.times[n - 1] {
            return (n - 1, n - 1, 0.0, 0.0);
        }
        // First key with time > t; t is strictly inside (times[0], times[n-1]).
        let k1 = self.times.partition_point(|&x| x <= t);
        let k0 = k1 - 1;
        let dt = self.times[k1] - self.times[k0];
        (k0, k1, (t - self.times[k0]) / dt, dt)
    }

    fn sample(&self, t: f32) -> Sampled {
        let (k0, k1, s, dt) = self.segment(t);
        match (&self.values, self.interpolation) {
            (Keyframes::Translation(v), i) => {
                Sampled::Translation(sample_vec3(v, i, k0, k1, s, dt))
            }
            (Keyframes::Scale(v), i) => Sampled::Scale(sample_vec3(v, i, k0, k1, s, dt)),
            (Keyframes::Rotation(v), Interpolation::Step) => Sampled::Rotation(v[k0].normalize()),
            (Keyframes::Rotation(v), Interpolation::Linear) => {
                Sampled::Rotation(slerp_short(v[k0].normalize(), v[k1].normalize(), s))
            }
            (Keyframes::Rotation(v), Interpolation::CubicSpline) => {
                let h = |q: Quat| Vec4::from(q);
                let r = hermite(
                    h(v[3 * k0 + 1]),
                    h(v[3 * k0 + 2]) * dt,
                    h(v[3 * k1 + 1]),
                    h(v[3 * k1]) * dt,
                    s,
                );
                Sampled::Rotation(Quat::from_vec4(r).normalize())
            }
            (Keyframes::Weights { targets, values }, i) => {
                let m = *targets;
                let entry = |k: usize| &values[k * m..(k + 1) * m];
                let w = match i {
                    Interpolation::Step => entry(k0).to_vec(),
                    Interpolation::Linear => entry(k0)
                        .iter()
                        .zip(entry(k1))
                        .map(|(a, b)| a + (b - a) * s)
                        .collect(),
                    Interpolation::CubicSpline => (0..m)
                        .map(|j| {
                            let c = |k: usize, part: usize| values[(3 * k + part) * m + j];
                            hermite_f32(c(k0, 1), c(k0, 2) * dt, c(k1, 1), c(k1, 0) * dt, s)
                        })
                        .collect(),
                };
                Sampled::Weights(w)
            }
        }
    }
}

fn sample_vec3(v: &[Vec3], i: Interpolation, k0: usize, k1: usize, s: f32, dt: f32) -> Vec3 {
    match i {
        Interpolation::Step => v[k0],
        Interpolation::Linear => v[k0].lerp(v[k1], s),
        Interpolation::CubicSpline => {
            let r = hermite(
                v[3 * k0 + 1].extend(0.0),
                v[3 * k0 + 2].extend(0.0) * dt,
                v[3 * k1 + 1].extend(0.0),
                v[3 * k1].extend(0.0) * dt,
                s,
            );
            r.truncate()
        }
    }
}

/// Cubic Hermite basis (glTF 2.0 Appendix C): `p0`, `m0` at `s = 0`, `p1`, `m1` at `s = 1`,
/// tangents already multiplied by the key interval.
fn hermite(p0: Vec4, m0: Vec4, p1: Vec4, m1: Vec4, s: f32) -> Vec4 {
    let s2 = s * s;
    let s3 = s2 * s;
    p0 * (2.0 * s3 - 3.0 * s2 + 1.0)
        + m0 * (s3 - 2.0 * s2 + s)
        + p1 * (-2.0 * s3 + 3.0 * s2)
        + m1 * (s3 - s2)
}

fn hermite_f32(p0: f32, m0: f32, p1: f32, m1: f32, s: f32) -> f32 {
    hermite(
        Vec4::splat(p0),
        Vec4::splat(m0),
        Vec4::splat(p1),
        Vec4::splat(m1),
        s,
    )
    .x
}

/// Spherical linear interpolation from `a` to `b` along the shorter arc (`b` is negated when
/// `a . b < 0`), exact to f32 rounding (no approximate `acos`). Falls back to normalised lerp
/// for nearly identical rotations.
pub fn slerp_short(a: Quat, b: Quat, s: f32) -> Quat {
    let mut b = b;
    let mut d = a.dot(b);
    if d < 0.0 {
        b = -b;
        d = -d;
    }
    if d > 0.9995 {
        return Quat::from_vec4(Vec4::from(a).lerp(Vec4::from(b), s)).normalize();
    }
    let theta = d.min(1.0).acos();
    let sin_theta = theta.sin();
    let wa = ((1.0 - s) * theta).sin() / sin_theta;
    let wb = (s * theta).sin() / sin_theta;
    Quat::from_vec4(Vec4::from(a) * wa + Vec4::from(b) * wb).normalize()
}

/// Which part of a node a channel animates, with its sampler.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Channel {
    /// Target node index.
    pub node: u32,
    /// Keyframes; their [`Keyframes`] variant names the animated property.
    pub sampler: Sampler,
}

/// A named animation: channels that are sampled together.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Clip {
    /// Name (may be empty).
    pub name: String,
    /// Channels in file order; later channels win when two target the same property.
    pub channels: Vec<Channel>,
}

impl Clip {
    /// Duration in seconds: the latest key time over all channels.
    pub fn duration(&self) -> f32 {
        self.channels
            .iter()
            .map(|c| c.sampler.end_time())
            .fold(0.0, f32::max)
    }

    /// Overwrites the animated properties of `pose` with their values at time `t` seconds
    /// (clamped to each channel's key range). Channels whose node is outside the pose are
    /// skipped.
    pub fn apply(&self, t: f32, pose: &mut Pose) {
        for channel in &self.channels {
            let node = channel.node as usize;
            let Some(local) = pose.locals.get_mut(node) else {
                continue;
            };
            let sampled = channel.sampler.sample(t);
            if let Sampled::Weights(w) = sampled {
                if let Some(slot) = pose.morph_weights.get_mut(node) {
                    *slot = Some(w);
                }
                continue;
            }
            let mut trs = local.to_trs();
            match sampled {
                Sampled::Translation(v) => trs.translation = v,
                Sampled::Rotation(q) => trs.rotation = q,
                Sampled::Scale(v) => trs.scale = v,
                Sampled::Weights(_) => {}
            }
            *local = LocalTransform::Trs(trs);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;
    use std::f32::consts::PI;

    #[test]
    fn slerp_takes_the_short_path_and_is_exact_at_midpoint() {
        // 10 deg and 350 deg about z: the short arc passes through 0 deg, not 180 deg.
        let a = Quat::from_rotation_z(10f32.to_radians());
        let b = Quat::from_rotation_z(350f32.to_radians());
        let m = slerp_short(a, b, 0.5);
        let v = m * Vec3::X;
        assert_relative_eq!(v.x, 1.0, epsilon = 1e-6);
        assert_relative_eq!(v.y, 0.0, epsilon = 1e-6);
        // Quarter of the way from 0 to 120 degrees is 30 degrees.
        let q = slerp_short(Quat::IDENTITY, Quat::from_rotation_z(2.0 * PI / 3.0), 0.25);
        let v = q * Vec3::X;
        assert_relative_eq!(v.y.atan2(v.x), PI / 6.0, epsilon = 1e-6);
    }

    #[test]
    fn sampler_counts_and_key_order_are_checked() {
        let e = Sampler::new(
            Interpolation::CubicSpline,
            vec![0.0, 1.0],
            Keyframes::Translation(vec![Vec3::ZERO; 2]),
        );
        assert_eq!(
            e,
            Err(AnimationError::SamplerCountMismatch {
                inputs: 2,
                expected: 6,
                outputs: 2
            })
        );
        let e = Sampler::new(
            Interpolation::Linear,
            vec![0.0, 0.0],
            Keyframes::Translation(vec![Vec3::ZERO; 2]),
        );
        assert_eq!(
            e,
            Err(AnimationError::UnsortedKeyframes { key: 1, time: 0.0 })
        );
    }

    #[test]
    fn cubic_spline_reproduces_a_cubic_polynomial() {
        // x(t) = t^3 on keys 0, 1, 2 with derivative 3 t^2 as tangents: Hermite is exact.
        let times = vec![0.0, 1.0, 2.0];
        let mut values = Vec::new();
        for &t in &times {
            let d = Vec3::new(3.0 * t * t, 0.0, 0.0);
            values.extend([d, Vec3::new(t * t * t, 0.0, 0.0), d]);
        }
        let s = Sampler::new(
            Interpolation::CubicSpline,
            times,
            Keyframes::Translation(values),
        )
        .unwrap();
        for t in [0.25f32, 0.5, 1.3, 1.9] {
            let Sampled::Translation(v) = s.sample(t) else {
                panic!("translation expected")
            };
            assert_relative_eq!(v.x, t * t * t, epsilon = 1e-5);
        }
        // Clamped outside the key range.
        assert_eq!(s.sample(-1.0), Sampled::Translation(Vec3::ZERO));
        assert_eq!(
            s.sample(5.0),
            Sampled::Translation(Vec3::new(8.0, 0.0, 0.0))
        );
    }
}
