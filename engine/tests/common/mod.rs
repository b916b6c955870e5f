//! Helpers shared by the engine's integration tests.

/// PSNR of two RGBA8 images over their RGB channels, in dB (infinite when identical).
pub fn psnr(a: &[[u8; 4]], b: &[[u8; 4]]) -> f64 {
    let mut se = 0f64;
    for (p, q) in a.iter().zip(b) {
        for k in 0..3 {
            let d = p[k] as f64 - q[k] as f64;
            se += d * d;
        }
    }
    let mse = se / (a.len() * 3) as f64;
    if mse == 0.0 {
        f64::INFINITY
    } else {
        10.0 * (255.0f64 * 255.0 / mse).log10()
    }
}
