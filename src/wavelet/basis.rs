//! Orthonormal wavelet bases: Haar, Daubechies and Coiflets, with PyWavelets' exact filter taps.
//!
//! # Names
//!
//! The number in a name is PyWavelets' (and MATLAB's): **the number of vanishing moments** of the
//! wavelet for Daubechies, the *order* for Coiflets. So `db2` has 4 taps (Daubechies' "D4"),
//! `db3` 6 taps (D6), `db4` 8 taps (D8), `coif1` 6 taps ("C6", 2 vanishing moments), `coif2`
//! 12 taps (C12). The issue's "Daubechies 4…8, Coiflets 6…12" are filter lengths: D4, D6, D8 =
//! `db2`, `db3`, `db4` and C6, C12 = `coif1`, `coif2`. Supported: `haar` (= `db1`), `db2`…`db10`
//! (2N taps) and `coif1`…`coif5` (6N taps). [`Basis::parse`] also accepts the filter-length
//! spellings `d4`…`d20` and `c6`…`c30`.
//!
//! # Filters
//!
//! [`Basis::lowpass`] and [`Basis::highpass`] are PyWavelets' decomposition filters `dec_lo` and
//! `dec_hi` in PyWavelets' order (`dec_lo` is the time-reversed scaling filter; `dec_hi[k] =
//! (−1)^(k+1)·dec_lo[F−1−k]`), generated once by `scripts/wavelet_taps.py` into `taps.rs`.
//! They are orthonormal: Σ h = √2, Σ h\[k\]·h\[k+2j\] = δ_j (checked in the tests to 1e-14).
//!
//! # Wire code
//!
//! [`Basis::code`] is a stable `u8`: Haar 1, Daubechies N → N (2..=10), Coiflet N → 16 + N
//! (17..=21). 0 is never used.

use super::taps::*;
use std::fmt;

/// An orthonormal wavelet basis.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(try_from = "String", into = "String")]
pub enum Basis {
    /// Haar (piecewise constant; 2 taps, 1 vanishing moment).
    Haar,
    /// Daubechies with N vanishing moments, 2N taps, N in 2..=10 (`db2` = D4).
    Daubechies(usize),
    /// Coiflet of order N, 6N taps, N in 1..=5 (`coif1` = C6).
    Coiflet(usize),
}

/// A basis name [`Basis::parse`] does not know.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown wavelet basis {0:?}: expected haar, db1..db10, coif1..coif5 (or d2..d20, c6..c30 by filter length)")]
pub struct UnknownBasis(pub String);

impl Basis {
    /// Every supported basis: Haar, db2..db10, coif1..coif5.
    pub fn all() -> Vec<Basis> {
        let mut all = vec![Basis::Haar];
        all.extend((2..=10).map(Basis::Daubechies));
        all.extend((1..=5).map(Basis::Coiflet));
        all
    }

    /// The bases the issue names: Haar, D4, D6, D8 (db2..db4), C6, C12 (coif1, coif2).
    pub fn issue_set() -> [Basis; 6] {
        [
            Basis::Haar,
            Basis::Daubechies(2),
            Basis::Daubechies(3),
            Basis::Daubechies(4),
            Basis::Coiflet(1),
            Basis::Coiflet(2),
        ]
    }

    /// Parses `haar`, `db1`..`db10` (vanishing moments), `coif1`..`coif5` (order), or the
    /// filter-length spellings `d2`..`d20` (even) and `c6`..`c30` (multiples of 6).
    /// Case-insensitive.
    pub fn parse(s: &str) -> Result<Basis, UnknownBasis> {
        let lower = s.trim().to_ascii_lowercase();
        let err = || UnknownBasis(s.to_string());
        let num = |rest: &str| rest.parse::<usize>().map_err(|_| err());
        let basis = if lower == "haar" {
            Basis::Haar
        } else if let Some(rest) = lower.strip_prefix("db") {
            Basis::Daubechies(num(rest)?)
        } else if let Some(rest) = lower.strip_prefix("coif") {
            Basis::Coiflet(num(rest)?)
        } else if let Some(rest) = lower.strip_prefix('d') {
            let taps = num(rest)?;
            if taps % 2 != 0 {
                return Err(err());
            }
            Basis::Daubechies(taps / 2)
        } else if let Some(rest) = lower.strip_prefix('c') {
            let taps = num(rest)?;
            if taps % 6 != 0 {
                return Err(err());
            }
            Basis::Coiflet(taps / 6)
        } else {
            return Err(err());
        };
        basis.normalized().ok_or_else(err)
    }

    /// `Daubechies(1)` is Haar; `None` for an unsupported number.
    fn normalized(self) -> Option<Basis> {
        match self {
            Basis::Haar | Basis::Daubechies(1) => Some(Basis::Haar),
            Basis::Daubechies(n) if (2..=10).contains(&n) => Some(self),
            Basis::Coiflet(n) if (1..=5).contains(&n) => Some(self),
            _ => None,
        }
    }

    /// Whether this value names a supported basis (the enum can hold unsupported numbers).
    pub fn is_supported(self) -> bool {
        self.normalized().is_some()
    }

    /// PyWavelets' name: `haar`, `db4`, `coif2`, … (`?` for an unsupported number).
    pub fn name(self) -> String {
        match self.normalized() {
            Some(Basis::Haar) => "haar".to_string(),
            Some(Basis::Daubechies(n)) => format!("db{n}"),
            Some(Basis::Coiflet(n)) => format!("coif{n}"),
            None => format!("{self:?}"),
        }
    }

    /// Number of filter taps (2 for Haar, 2N for dbN, 6N for coifN).
    pub fn taps(self) -> usize {
        self.lowpass().len()
    }

    /// Vanishing moments of the wavelet (1 for Haar, N for dbN, 2N for coifN).
    pub fn vanishing_moments(self) -> usize {
        match self.normalized() {
            Some(Basis::Daubechies(n)) => n,
            Some(Basis::Coiflet(n)) => 2 * n,
            _ => 1,
        }
    }

    /// PyWavelets' decomposition low-pass filter `dec_lo`. An unsupported number falls back to
    /// Haar (construct bases with [`Basis::parse`] or [`Basis::from_code`] to avoid that).
    pub fn lowpass(self) -> &'static [f64] {
        match self.normalized() {
            Some(Basis::Daubechies(2)) => &DB2_LO,
            Some(Basis::Daubechies(3)) => &DB3_LO,
            Some(Basis::Daubechies(4)) => &DB4_LO,
            Some(Basis::Daubechies(5)) => &DB5_LO,
            Some(Basis::Daubechies(6)) => &DB6_LO,
            Some(Basis::Daubechies(7)) => &DB7_LO,
            Some(Basis::Daubechies(8)) => &DB8_LO,
            Some(Basis::Daubechies(9)) => &DB9_LO,
            Some(Basis::Daubechies(10)) => &DB10_LO,
            Some(Basis::Coiflet(1)) => &COIF1_LO,
            Some(Basis::Coiflet(2)) => &COIF2_LO,
            Some(Basis::Coiflet(3)) => &COIF3_LO,
            Some(Basis::Coiflet(4)) => &COIF4_LO,
            Some(Basis::Coiflet(5)) => &COIF5_LO,
            _ => &HAAR_LO,
        }
    }

    /// PyWavelets' decomposition high-pass filter `dec_hi` (same fallback as [`Basis::lowpass`]).
    pub fn highpass(self) -> &'static [f64] {
        match self.normalized() {
            Some(Basis::Daubechies(2)) => &DB2_HI,
            Some(Basis::Daubechies(3)) => &DB3_HI,
            Some(Basis::Daubechies(4)) => &DB4_HI,
            Some(Basis::Daubechies(5)) => &DB5_HI,
            Some(Basis::Daubechies(6)) => &DB6_HI,
            Some(Basis::Daubechies(7)) => &DB7_HI,
            Some(Basis::Daubechies(8)) => &DB8_HI,
            Some(Basis::Daubechies(9)) => &DB9_HI,
            Some(Basis::Daubechies(10)) => &DB10_HI,
            Some(Basis::Coiflet(1)) => &COIF1_HI,
            Some(Basis::Coiflet(2)) => &COIF2_HI,
            Some(Basis::Coiflet(3)) => &COIF3_HI,
            Some(Basis::Coiflet(4)) => &COIF4_HI,
            Some(Basis::Coiflet(5)) => &COIF5_HI,
            _ => &HAAR_HI,
        }
    }

    /// Stable wire code: Haar 1, dbN → N, coifN → 16 + N (see the module documentation).
    pub fn code(self) -> u8 {
        match self.normalized() {
            Some(Basis::Daubechies(n)) => n as u8,
            Some(Basis::Coiflet(n)) => 16 + n as u8,
            _ => 1,
        }
    }

    /// The basis of a wire code, `None` for an unknown code.
    pub fn from_code(code: u8) -> Option<Basis> {
        match code {
            1 => Some(Basis::Haar),
            2..=10 => Some(Basis::Daubechies(code as usize)),
            17..=21 => Some(Basis::Coiflet(code as usize - 16)),
            _ => None,
        }
    }
}

impl fmt::Display for Basis {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.name())
    }
}

impl std::str::FromStr for Basis {
    type Err = UnknownBasis;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Basis::parse(s)
    }
}

impl TryFrom<String> for Basis {
    type Error = UnknownBasis;
    fn try_from(s: String) -> Result<Self, Self::Error> {
        Basis::parse(&s)
    }
}

impl From<Basis> for String {
    fn from(b: Basis) -> String {
        b.name()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_parse_and_codes_round_trip() {
        for b in Basis::all() {
            assert_eq!(Basis::parse(&b.name()).unwrap(), b);
            assert_eq!(Basis::from_code(b.code()).unwrap(), b);
        }
        assert_eq!(Basis::parse("D4").unwrap(), Basis::Daubechies(2));
        assert_eq!(Basis::parse("d8").unwrap(), Basis::Daubechies(4));
        assert_eq!(Basis::parse("c12").unwrap(), Basis::Coiflet(2));
        assert_eq!(Basis::parse("db1").unwrap(), Basis::Haar);
        for bad in [
            "", "db", "db11", "coif0", "coif6", "d5", "c7", "sym4", "db-1",
        ] {
            assert!(Basis::parse(bad).is_err(), "{bad:?} should not parse");
        }
        let codes: std::collections::HashSet<u8> = Basis::all().iter().map(|b| b.code()).collect();
        assert_eq!(codes.len(), Basis::all().len());
    }

    #[test]
    fn filters_are_orthonormal_with_vanishing_moments() {
        for b in Basis::all() {
            let (h, g) = (b.lowpass(), b.highpass());
            let f = h.len();
            assert_eq!(g.len(), f);
            let want_taps = match b {
                Basis::Haar => 2,
                Basis::Daubechies(n) => 2 * n,
                Basis::Coiflet(n) => 6 * n,
            };
            assert_eq!(f, want_taps, "{b}");
            let sum: f64 = h.iter().sum();
            assert!((sum - 2f64.sqrt()).abs() < 1e-14, "{b}: Σh = {sum}");
            for shift in (0..f).step_by(2) {
                let hh: f64 = (0..f - shift).map(|k| h[k] * h[k + shift]).sum();
                let gg: f64 = (0..f - shift).map(|k| g[k] * g[k + shift]).sum();
                let want = if shift == 0 { 1.0 } else { 0.0 };
                assert!((hh - want).abs() < 1e-14, "{b}: lo shift {shift}: {hh}");
                assert!((gg - want).abs() < 1e-14, "{b}: hi shift {shift}: {gg}");
            }
            // Vanishing moments: Σ k^p g[k] = 0 for p < moments (relative to the scale of k^p).
            for p in 0..b.vanishing_moments() {
                let (mut m, mut scale) = (0.0, 0.0);
                for (k, &gk) in g.iter().enumerate() {
                    let kp = (k as f64).powi(p as i32);
                    m += kp * gk;
                    scale += kp * gk.abs();
                }
                assert!(m.abs() < 1e-9 * scale, "{b}: moment {p} = {m}");
            }
        }
    }
}
