//! The band limit applied to accelerometer and gyroscope samples before they are interpolated onto
//! the output grid: a second-order Butterworth low-pass run at the sensor's rate, so that content
//! above the output's Nyquist frequency does not alias into the resampled signal.

/// Coefficients of a second-order Butterworth low-pass, `y[n] = b0 x[n] + b1 x[n-1] + b2 x[n-2]
/// - a1 y[n-1] - a2 y[n-2]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Butterworth2 {
    b: [f64; 3],
    a: [f64; 2],
}

impl Butterworth2 {
    /// The low-pass with cutoff `cutoff_hz` at sample rate `rate_hz`, by the bilinear transform
    /// with the cutoff pre-warped (the analog prototype `1 / (s² + √2 s + 1)`), so the digital
    /// filter's -3 dB point is exactly `cutoff_hz`. `None` unless `0 < cutoff_hz < rate_hz / 2`.
    pub fn lowpass(cutoff_hz: f64, rate_hz: f64) -> Option<Butterworth2> {
        let valid = cutoff_hz.is_finite() && rate_hz.is_finite() && cutoff_hz > 0.0;
        if !valid || cutoff_hz >= rate_hz / 2.0 {
            return None;
        }
        let k = (std::f64::consts::PI * cutoff_hz / rate_hz).tan();
        let sqrt2 = std::f64::consts::SQRT_2;
        let norm = 1.0 / (1.0 + sqrt2 * k + k * k);
        let b0 = k * k * norm;
        Some(Butterworth2 {
            b: [b0, 2.0 * b0, b0],
            a: [2.0 * (k * k - 1.0) * norm, (1.0 - sqrt2 * k + k * k) * norm],
        })
    }

    /// The group delay at 0 Hz in samples: for `H(z) = B(z)/A(z)` it is
    /// `Σ n·b_n / Σ b_n − Σ n·a_n / Σ a_n` (with `a_0 = 1`). Human motion lies far below the cutoff,
    /// where the delay is flat to within a few percent, so shifting the filtered samples back by it
    /// re-aligns them with the orientation.
    pub fn group_delay_samples(&self) -> f64 {
        let [b0, b1, b2] = self.b;
        let [a1, a2] = self.a;
        (b1 + 2.0 * b2) / (b0 + b1 + b2) - (a1 + 2.0 * a2) / (1.0 + a1 + a2)
    }

    /// The gain at frequency `f_hz` for sample rate `rate_hz` (for tests and docs).
    pub fn gain(&self, f_hz: f64, rate_hz: f64) -> f64 {
        let w = 2.0 * std::f64::consts::PI * f_hz / rate_hz;
        let (c1, s1, c2, s2) = (w.cos(), w.sin(), (2.0 * w).cos(), (2.0 * w).sin());
        let [b0, b1, b2] = self.b;
        let [a1, a2] = self.a;
        let num = ((b0 + b1 * c1 + b2 * c2).powi(2) + (b1 * s1 + b2 * s2).powi(2)).sqrt();
        let den = ((1.0 + a1 * c1 + a2 * c2).powi(2) + (a1 * s1 + a2 * s2).powi(2)).sqrt();
        num / den
    }
}

/// The filter applied to each axis of a 3-vector (transposed direct form II), started in the
/// steady state of its first input so that it has no start-up transient.
#[derive(Clone, Debug)]
pub struct VecLowpass {
    coeffs: Butterworth2,
    state: Option<[[f64; 2]; 3]>,
}

impl VecLowpass {
    pub fn new(coeffs: Butterworth2) -> VecLowpass {
        VecLowpass {
            coeffs,
            state: None,
        }
    }

    /// Filters one sample.
    pub fn step(&mut self, x: [f64; 3]) -> [f64; 3] {
        let Butterworth2 { b, a } = self.coeffs;
        // Steady state for a constant input x (the DC gain is 1, so y = x).
        let state = self.state.get_or_insert_with(|| {
            x.map(|v| {
                let z2 = (b[2] - a[1]) * v;
                [(b[1] - a[0]) * v + z2, z2]
            })
        });
        let mut y = [0.0; 3];
        for axis in 0..3 {
            let [z1, z2] = state[axis];
            let out = b[0] * x[axis] + z1;
            state[axis] = [
                b[1] * x[axis] - a[0] * out + z2,
                b[2] * x[axis] - a[1] * out,
            ];
            y[axis] = out;
        }
        y
    }

    /// Forgets the past: the next sample starts the filter again (after a long gap, where the
    /// signal before it says nothing about the signal after it).
    pub fn reset(&mut self) {
        self.state = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cutoff_is_at_minus_3_db_and_the_dc_gain_is_one() {
        let f = Butterworth2::lowpass(24.0, 200.0).unwrap();
        assert!((f.gain(0.0, 200.0) - 1.0).abs() < 1e-12);
        assert!((f.gain(24.0, 200.0) - std::f64::consts::FRAC_1_SQRT_2).abs() < 1e-9);
        // Second order: -40 dB/decade well above the cutoff (bilinear: even steeper near Nyquist).
        assert!(f.gain(80.0, 200.0) < 0.1);
        assert!(Butterworth2::lowpass(100.0, 200.0).is_none());
        assert!(Butterworth2::lowpass(0.0, 200.0).is_none());
    }

    #[test]
    fn the_dc_group_delay_matches_the_analog_prototype_and_a_measured_ramp_lag() {
        // Analog 2nd-order Butterworth: τ(0) = √2 / ω_c; the bilinear transform keeps it closely
        // when the cutoff is far below the sample rate.
        let rate = 2000.0;
        let f = Butterworth2::lowpass(24.0, rate).unwrap();
        let analog = std::f64::consts::SQRT_2 / (2.0 * std::f64::consts::PI * 24.0);
        let digital = f.group_delay_samples() / rate;
        assert!(
            (digital - analog).abs() < 0.01 * analog,
            "{digital} {analog}"
        );
        // A ramp through the filter lags by exactly the DC group delay once settled.
        let f = Butterworth2::lowpass(24.0, 200.0).unwrap();
        let mut lp = VecLowpass::new(f);
        let mut y = [0.0; 3];
        for n in 0..2000 {
            y = lp.step([n as f64, 0.0, -(n as f64)]);
        }
        let lag = 1999.0 - y[0];
        assert!((lag - f.group_delay_samples()).abs() < 1e-6, "{lag}");
        assert!((y[0] + y[2]).abs() < 1e-9);
    }

    #[test]
    fn a_constant_input_passes_unchanged_from_the_first_sample() {
        let mut lp = VecLowpass::new(Butterworth2::lowpass(10.0, 100.0).unwrap());
        for _ in 0..5 {
            let y = lp.step([9.81, -1.0, 0.5]);
            assert!((y[0] - 9.81).abs() < 1e-12 && (y[1] + 1.0).abs() < 1e-12);
        }
        lp.reset();
        let y = lp.step([1.0, 2.0, 3.0]);
        assert!((y[2] - 3.0).abs() < 1e-12);
    }
}
