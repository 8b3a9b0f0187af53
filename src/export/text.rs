//! Deterministic float text: shortest representation that round-trips (`ryu`).

/// Appends the shortest decimal text of `x` that parses back to the same `f32` bits.
pub(super) fn push_f32(out: &mut String, x: f32) {
    let mut buf = ryu::Buffer::new();
    out.push_str(buf.format(x));
}

/// Appends `x y z` separated by `sep`.
pub(super) fn push_vec3(out: &mut String, v: [f32; 3], sep: &str) {
    push_f32(out, v[0]);
    out.push_str(sep);
    push_f32(out, v[1]);
    out.push_str(sep);
    push_f32(out, v[2]);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn float_text_round_trips_bits() {
        for x in [
            0.1f32,
            -0.0,
            1.0,
            1e-30,
            3.4e38,
            1.0 / 3.0,
            f32::MIN_POSITIVE,
        ] {
            let mut s = String::new();
            push_f32(&mut s, x);
            assert_eq!(s.parse::<f32>().unwrap().to_bits(), x.to_bits(), "{s}");
        }
    }
}
