//! Conversions between scene types and their wire mirrors in `lightfold-protocol` (the plan carries
//! explicit light samples and cameras; nodes never resample).

use crate::model::{AreaShape, Camera, LightSample, SampleKind, ShadowFilter};
use lightfold_protocol::{CELL_FILTER, WireArea, WireCamera, WireLight};

/// Taps per axis a grid or cell filter may have.
pub const MAX_FILTER_TAPS: u32 = 15;

/// The wire code of a shadow filter (`NodeConfig::filter`): 0 none, 1 PCF 2×2, n an n×n grid,
/// [`CELL_FILTER`] + n the cell filter with n×n taps.
pub fn filter_to_wire(f: ShadowFilter) -> u32 {
    match f {
        ShadowFilter::None => 0,
        ShadowFilter::Pcf2x2 => 1,
        ShadowFilter::Pcf { taps } => taps.clamp(2, MAX_FILTER_TAPS),
        ShadowFilter::Cell { taps } => CELL_FILTER + taps.clamp(2, MAX_FILTER_TAPS),
    }
}

/// The shadow filter of a wire code, `None` for a code no filter has.
pub fn filter_from_wire(code: u32) -> Option<ShadowFilter> {
    match code {
        0 => Some(ShadowFilter::None),
        1 => Some(ShadowFilter::Pcf2x2),
        taps @ 2..=MAX_FILTER_TAPS => Some(ShadowFilter::Pcf { taps }),
        c if (CELL_FILTER + 2..=CELL_FILTER + MAX_FILTER_TAPS).contains(&c) => {
            Some(ShadowFilter::Cell {
                taps: c - CELL_FILTER,
            })
        }
        _ => None,
    }
}

/// The wire form of a sample; `sample` is its index in the scene's full sample list.
pub fn light_to_wire(s: &LightSample, sample: u32) -> WireLight {
    let (kind, cone) = match s.kind {
        SampleKind::Isotropic => (0, [0.0, 0.0]),
        SampleKind::CosineLobe => (1, [0.0, 0.0]),
        SampleKind::TwoSidedLobe => (2, [0.0, 0.0]),
        SampleKind::Spot {
            cos_outer,
            cos_inner,
        } => (3, [cos_outer, cos_inner]),
        SampleKind::Directional => (4, [0.0, 0.0]),
        SampleKind::Bounce { clamp } => (5, [clamp, 0.0]),
    };
    WireLight {
        position: s.position,
        direction: s.direction,
        kind,
        cone,
        intensity: s.intensity,
        color: s.color,
        range: s.range.unwrap_or(0.0),
        light: s.light,
        sample,
        area: s.area.map(area_to_wire),
        cell: s.cell,
    }
}

fn area_to_wire(a: AreaShape) -> WireArea {
    match a {
        AreaShape::Rect { center, u, v } => WireArea {
            kind: 0,
            center,
            u,
            v,
        },
        AreaShape::Disk { center, u, v } => WireArea {
            kind: 1,
            center,
            u,
            v,
        },
        AreaShape::Sphere { center, radius } => WireArea {
            kind: 2,
            center,
            u: [radius, 0.0, 0.0],
            v: [0.0; 3],
        },
    }
}

fn area_from_wire(a: &WireArea, sample: u32) -> Result<AreaShape, WireError> {
    let finite = a
        .center
        .iter()
        .chain(a.u.iter())
        .chain(a.v.iter())
        .all(|v| v.is_finite());
    if !finite {
        return Err(WireError::NonFinite { sample });
    }
    let (center, u, v) = (a.center, a.u, a.v);
    match a.kind {
        0 => Ok(AreaShape::Rect { center, u, v }),
        1 => Ok(AreaShape::Disk { center, u, v }),
        2 if u[0] >= 0.0 => Ok(AreaShape::Sphere {
            center,
            radius: u[0],
        }),
        2 => Err(WireError::NegativeRadius { sample }),
        kind => Err(WireError::UnknownArea { sample, kind }),
    }
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum WireError {
    #[error("light sample {sample} has unknown kind {kind}")]
    UnknownKind { sample: u32, kind: u8 },
    #[error("light sample {sample} has unknown area shape {kind}")]
    UnknownArea { sample: u32, kind: u8 },
    #[error("light sample {sample} has a sphere light of negative radius")]
    NegativeRadius { sample: u32 },
    #[error("light sample {sample} has a cell of negative width")]
    NegativeCell { sample: u32 },
    #[error("light sample {sample} has a non-finite field")]
    NonFinite { sample: u32 },
    #[error("camera is invalid: {0}")]
    Camera(&'static str),
    #[error("camera is invalid: {0}")]
    Limit(#[from] crate::limits::LimitError),
}

/// The scene form of a wire sample, validated (input from the network).
pub fn light_from_wire(w: &WireLight) -> Result<LightSample, WireError> {
    let finite = w
        .position
        .iter()
        .chain(w.direction.iter())
        .chain(w.color.iter())
        .chain(w.cone.iter())
        .all(|v| v.is_finite())
        && w.intensity.is_finite()
        && w.range.is_finite()
        && w.cell.is_finite();
    if !finite {
        return Err(WireError::NonFinite { sample: w.sample });
    }
    if w.cell < 0.0 {
        return Err(WireError::NegativeCell { sample: w.sample });
    }
    let kind = match w.kind {
        0 => SampleKind::Isotropic,
        1 => SampleKind::CosineLobe,
        2 => SampleKind::TwoSidedLobe,
        3 => SampleKind::Spot {
            cos_outer: w.cone[0],
            cos_inner: w.cone[1],
        },
        4 => SampleKind::Directional,
        5 => SampleKind::Bounce {
            clamp: w.cone[0].max(0.0),
        },
        kind => {
            return Err(WireError::UnknownKind {
                sample: w.sample,
                kind,
            });
        }
    };
    Ok(LightSample {
        position: w.position,
        direction: w.direction,
        kind,
        intensity: w.intensity,
        color: w.color,
        range: (w.range > 0.0).then_some(w.range),
        light: w.light,
        area: w
            .area
            .as_ref()
            .map(|a| area_from_wire(a, w.sample))
            .transpose()?,
        cell: w.cell,
    })
}

pub fn camera_to_wire(c: &Camera) -> WireCamera {
    WireCamera {
        position: c.position,
        target: c.target,
        up: c.up,
        fov_y_deg: c.fov_y_deg,
        width: c.width,
        height: c.height,
    }
}

pub fn camera_from_wire(w: &WireCamera) -> Result<Camera, WireError> {
    let finite = w
        .position
        .iter()
        .chain(w.target.iter())
        .chain(w.up.iter())
        .all(|v| v.is_finite())
        && w.fov_y_deg.is_finite();
    if !finite {
        return Err(WireError::Camera("non-finite field"));
    }
    if !(w.fov_y_deg > 0.0 && w.fov_y_deg < 180.0) {
        return Err(WireError::Camera(
            "vertical field of view must be in (0, 180) degrees",
        ));
    }
    // The same limits as every other place that takes an image size.
    crate::limits::check_image_size(w.width, w.height)?;
    if w.position == w.target {
        return Err(WireError::Camera("position equals target"));
    }
    Ok(Camera {
        position: w.position,
        target: w.target,
        up: w.up,
        fov_y_deg: w.fov_y_deg,
        width: w.width,
        height: w.height,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn samples_round_trip() {
        let kinds = [
            SampleKind::Isotropic,
            SampleKind::CosineLobe,
            SampleKind::TwoSidedLobe,
            SampleKind::Spot {
                cos_outer: 0.5,
                cos_inner: 0.9,
            },
            SampleKind::Directional,
            SampleKind::Bounce { clamp: 0.25 },
        ];
        for (i, kind) in kinds.into_iter().enumerate() {
            let s = LightSample {
                position: [1.0, 2.0, 3.0],
                direction: [0.0, -1.0, 0.0],
                kind,
                intensity: 4.5,
                color: [1.0, 0.5, 0.25],
                range: if i % 2 == 0 { Some(7.0) } else { None },
                light: 3,
                area: None,
                cell: 0.0,
            };
            assert_eq!(light_from_wire(&light_to_wire(&s, i as u32)).unwrap(), s);
        }
        let mut bad = light_to_wire(
            &LightSample {
                position: [0.0; 3],
                direction: [0.0; 3],
                kind: SampleKind::Isotropic,
                intensity: 1.0,
                color: [1.0; 3],
                range: None,
                light: 0,
                area: None,
                cell: 0.0,
            },
            9,
        );
        bad.kind = 17;
        assert_eq!(
            light_from_wire(&bad),
            Err(WireError::UnknownKind {
                sample: 9,
                kind: 17
            })
        );
        bad.kind = 0;
        bad.intensity = f32::NAN;
        assert_eq!(
            light_from_wire(&bad),
            Err(WireError::NonFinite { sample: 9 })
        );
    }

    #[test]
    fn area_shapes_round_trip_and_are_validated() {
        let shapes = [
            AreaShape::Rect {
                center: [0.0, 2.0, 0.0],
                u: [0.5, 0.0, 0.0],
                v: [0.0, 0.0, 0.25],
            },
            AreaShape::Disk {
                center: [1.0, 2.0, 0.0],
                u: [0.3, 0.0, 0.0],
                v: [0.0, 0.3, 0.0],
            },
            AreaShape::Sphere {
                center: [0.0, 3.0, 1.0],
                radius: 0.2,
            },
        ];
        for (i, area) in shapes.into_iter().enumerate() {
            let s = LightSample {
                position: [1.0, 2.0, 3.0],
                direction: [0.0, -1.0, 0.0],
                kind: SampleKind::CosineLobe,
                intensity: 4.5,
                color: [1.0; 3],
                range: None,
                light: 1,
                area: Some(area),
                cell: 0.0,
            };
            assert_eq!(light_from_wire(&light_to_wire(&s, i as u32)).unwrap(), s);
        }
        let s = LightSample {
            area: Some(shapes[2]),
            ..light_from_wire(&light_to_wire(
                &LightSample {
                    position: [0.0; 3],
                    direction: [0.0, 1.0, 0.0],
                    kind: SampleKind::CosineLobe,
                    intensity: 1.0,
                    color: [1.0; 3],
                    range: None,
                    light: 0,
                    area: None,
                    cell: 0.0,
                },
                4,
            ))
            .unwrap()
        };
        let mut bad = light_to_wire(&s, 4);
        bad.area.as_mut().unwrap().kind = 9;
        assert_eq!(
            light_from_wire(&bad),
            Err(WireError::UnknownArea { sample: 4, kind: 9 })
        );
        let mut bad = light_to_wire(&s, 4);
        bad.area.as_mut().unwrap().u[0] = -1.0;
        assert_eq!(
            light_from_wire(&bad),
            Err(WireError::NegativeRadius { sample: 4 })
        );
        let mut bad = light_to_wire(&s, 4);
        bad.area.as_mut().unwrap().center[1] = f32::INFINITY;
        assert_eq!(
            light_from_wire(&bad),
            Err(WireError::NonFinite { sample: 4 })
        );
    }

    #[test]
    fn cameras_are_validated() {
        let c = Camera {
            position: [0.0, 1.0, 5.0],
            target: [0.0; 3],
            up: [0.0, 1.0, 0.0],
            fov_y_deg: 45.0,
            width: 64,
            height: 48,
        };
        assert_eq!(camera_from_wire(&camera_to_wire(&c)).unwrap(), c);
        let mut w = camera_to_wire(&c);
        w.width = 0;
        assert!(camera_from_wire(&w).is_err());
        let mut w = camera_to_wire(&c);
        w.fov_y_deg = f32::INFINITY;
        assert!(camera_from_wire(&w).is_err());
        // 16384 per side used to pass here and then panic in wgpu.
        let mut w = camera_to_wire(&c);
        (w.width, w.height) = (16384, 16384);
        let e = camera_from_wire(&w).unwrap_err();
        assert!(e.to_string().contains("at most 8192 per side"), "{e}");
        (w.width, w.height) = (4096, 4096);
        assert!(camera_from_wire(&w).is_ok());
    }
}
