//! The hard cases of numerical stability (issue 12): each a scene, a metric against ground truth,
//! an asserted bound chosen from measurement (docs/hard-cases.md) and a negative control — the
//! same case with a known mistake — that must break the bound, so the bound can fail. Every case
//! also counts non-finite values anywhere it looks; any NaN or Inf fails it.
//!
//! Each case has a small version (the CI tests) and a full-size one (`lightfold accuracy --hard`).

mod banding;
mod chain;
mod degenerate;
mod depth_range;
pub mod glossy;
mod shadow;
pub mod shadow_maps;
mod subtexel;
mod subtexel_scene;
mod support;

use std::fmt;

/// What one run of a hard case measured.
#[derive(Debug, Clone, PartialEq)]
pub struct CaseReport {
    pub name: &'static str,
    /// What the metric measures (smaller is better for every case).
    pub metric: &'static str,
    pub measured: f64,
    /// The asserted upper bound on `measured`.
    pub bound: f64,
    /// The deliberate mistake of the negative control.
    pub control: &'static str,
    /// The metric on the negative control; it must exceed `bound`.
    pub control_value: f64,
    /// NaN or Inf values found in the case proper (images, bands, sums).
    pub non_finite: usize,
    /// Further figures worth printing (per band, per order, per N…).
    pub details: Vec<String>,
}

impl CaseReport {
    /// The case holds: within its bound, no non-finite value, and the control breaks the bound.
    pub fn passes(&self) -> bool {
        self.within_bound() && self.control_fails()
    }

    pub fn within_bound(&self) -> bool {
        self.non_finite == 0 && self.measured.is_finite() && self.measured <= self.bound
    }

    /// NaN counts as a failure of the control too (it cannot be within the bound).
    pub fn control_fails(&self) -> bool {
        self.control_value.is_nan() || self.control_value > self.bound
    }
}

impl fmt::Display for CaseReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "{:<12} {}: {:.4e} (bound {:.4e}, non-finite {}) {}",
            self.name,
            self.metric,
            self.measured,
            self.bound,
            self.non_finite,
            if self.passes() { "ok" } else { "FAIL" }
        )?;
        write!(
            f,
            "{:<12} control ({}): {:.4e} {}",
            "",
            self.control,
            self.control_value,
            if self.control_fails() {
                "fails the bound, as it must"
            } else {
                "WITHIN THE BOUND (the test cannot fail)"
            }
        )?;
        for d in &self.details {
            write!(f, "\n{:<12} {d}", "")?;
        }
        Ok(())
    }
}

#[derive(Debug, thiserror::Error)]
pub enum HardCaseError {
    #[error("unknown hard case {name:?}; known: {known}")]
    UnknownCase { name: String, known: String },
    #[error("gpu: {message}")]
    Gpu { message: String },
    #[error("render of case {case}: {message}")]
    Render { case: &'static str, message: String },
    #[error("scene of case {case}: {source}")]
    Scene {
        case: &'static str,
        #[source]
        source: lightfold_scene::SceneError,
    },
    #[error("pixel format in case {case}: {source}")]
    Format {
        case: &'static str,
        #[source]
        source: lightfold_protocol::format::FormatError,
    },
    #[error("compositor operator in case {case}: {message}")]
    Operator { case: &'static str, message: String },
}

type CaseFn = fn(bool) -> Result<CaseReport, HardCaseError>;

/// The implemented cases, most valuable first (issue 12's numbering in docs/hard-cases.md).
const CASES: &[(&str, CaseFn)] = &[
    ("chain64", chain::chain64),
    ("hdr-mix", chain::hdr_mix),
    ("grazing", shadow::grazing),
    ("thin-wall", shadow::thin_wall),
    ("near-light", shadow::near_light),
    ("many-lights", chain::many_lights),
    ("degenerate", degenerate::degenerate),
    ("contact", shadow::contact),
    ("terminator", shadow::terminator),
    ("depth-range", depth_range::depth_range),
    ("banding", banding::banding_case),
    ("subtexel-leaves", subtexel::subtexel_leaves),
    ("subtexel-fence", subtexel::subtexel_fence),
    ("corner-leak", shadow_maps::corner_leak),
    ("grazing-fin", shadow_maps::grazing_fin),
    ("deep-near", shadow_maps::deep_near),
    ("thin-poles", shadow_maps::thin_poles),
    ("thin-house", shadow_maps::thin_house),
    ("cornell-junction", shadow_maps::cornell_junction),
    ("glossy-area", glossy::glossy_area),
];

/// Names of the hard cases `run_case` knows.
pub fn case_names() -> Vec<&'static str> {
    CASES.iter().map(|(n, _)| *n).collect()
}

/// Runs one hard case: the small CI version, or the full-size one when `full_size`.
pub fn run_case(name: &str, full_size: bool) -> Result<CaseReport, HardCaseError> {
    let (_, f) =
        CASES
            .iter()
            .find(|(n, _)| *n == name)
            .ok_or_else(|| HardCaseError::UnknownCase {
                name: name.to_string(),
                known: case_names().join(", "),
            })?;
    f(full_size)
}
