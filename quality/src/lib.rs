//! lightfold's quality measurements: the hard cases of numerical stability (each a scene, a metric
//! against ground truth, an asserted bound and a negative control) and the speed-against-error
//! sweep behind `lightfold accuracy`.
//!
//! Uses the GPU renderer and the CPU reference side by side; nothing here runs in a daemon.

pub mod accuracy;
pub mod hard;
