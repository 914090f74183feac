//! The problems validation reports, and their report.

use std::fmt;

/// One problem found (and, by [`Scene::sanitize`], fixed).
#[derive(Debug, Clone, PartialEq)]
pub enum Issue {
    AttributeCount {
        mesh: String,
        attribute: &'static str,
        found: usize,
        expected: usize,
    },
    TruncatedIndices {
        mesh: String,
        len: usize,
    },
    NonFinitePositions {
        mesh: String,
        count: usize,
    },
    IndexOutOfRange {
        mesh: String,
        count: usize,
    },
    DegenerateTriangles {
        mesh: String,
        count: usize,
    },
    BadNormals {
        mesh: String,
        count: usize,
    },
    NonFiniteUvs {
        mesh: String,
        count: usize,
    },
    EmptyMesh {
        mesh: String,
    },
    MaterialOutOfRange {
        mesh: String,
        material: usize,
    },
    BadMaterial {
        material: String,
    },
    BadTangents {
        mesh: String,
    },
    TextureOutOfRange {
        material: String,
        texture: usize,
    },
    TextureSize {
        texture: String,
    },
    BadLight {
        light: String,
        problem: &'static str,
    },
    BadCamera {
        problem: &'static str,
    },
    BadExposure,
    BadQuality {
        problem: &'static str,
    },
    /// The animation does not fit the scene or holds bad values; it is dropped (the scene stays
    /// in its rest pose).
    BadAnimation {
        problem: String,
    },
}

impl fmt::Display for Issue {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Issue::AttributeCount {
                mesh,
                attribute,
                found,
                expected,
            } => write!(
                f,
                "mesh {mesh:?}: {found} {attribute} for {expected} positions"
            ),
            Issue::TruncatedIndices { mesh, len } => {
                write!(f, "mesh {mesh:?}: {len} indices is not a multiple of 3")
            }
            Issue::NonFinitePositions { mesh, count } => {
                write!(f, "mesh {mesh:?}: {count} non-finite positions")
            }
            Issue::IndexOutOfRange { mesh, count } => {
                write!(
                    f,
                    "mesh {mesh:?}: {count} triangles with out-of-range indices"
                )
            }
            Issue::DegenerateTriangles { mesh, count } => {
                write!(
                    f,
                    "mesh {mesh:?}: {count} zero-area or non-finite triangles"
                )
            }
            Issue::BadNormals { mesh, count } => {
                write!(f, "mesh {mesh:?}: {count} zero or non-finite normals")
            }
            Issue::NonFiniteUvs { mesh, count } => {
                write!(f, "mesh {mesh:?}: {count} non-finite texture coordinates")
            }
            Issue::EmptyMesh { mesh } => write!(f, "mesh {mesh:?} has no usable triangles"),
            Issue::MaterialOutOfRange { mesh, material } => {
                write!(f, "mesh {mesh:?} names missing material {material}")
            }
            Issue::BadMaterial { material } => {
                write!(f, "material {material:?} has non-finite or negative values")
            }
            Issue::BadTangents { mesh } => {
                write!(f, "mesh {mesh:?} has non-finite tangents (dropped)")
            }
            Issue::TextureOutOfRange { material, texture } => {
                write!(f, "material {material:?} names missing texture {texture}")
            }
            Issue::TextureSize { texture } => {
                write!(f, "texture {texture:?}: pixel data does not match its size")
            }
            Issue::BadLight { light, problem } => write!(f, "light {light:?}: {problem}"),
            Issue::BadCamera { problem } => write!(f, "camera: {problem}"),
            Issue::BadExposure => write!(f, "exposure is not a positive finite number"),
            Issue::BadQuality { problem } => write!(f, "quality: {problem}"),
            Issue::BadAnimation { problem } => write!(f, "animation dropped: {problem}"),
        }
    }
}

/// Everything [`Scene::validate`] or [`Scene::sanitize`] found.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ValidationReport {
    pub issues: Vec<Issue>,
}

impl ValidationReport {
    pub fn is_clean(&self) -> bool {
        self.issues.is_empty()
    }
}

impl fmt::Display for ValidationReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.issues.is_empty() {
            return write!(f, "no issues");
        }
        for (i, issue) in self.issues.iter().enumerate() {
            if i > 0 {
                write!(f, "; ")?;
            }
            write!(f, "{issue}")?;
        }
        Ok(())
    }
}
