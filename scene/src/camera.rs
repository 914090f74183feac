//! Camera conventions (ARCHITECTURE §3): right-handed, Y up, vertical field of view, image row 0 at
//! the top, pixel centres at +0.5. The GPU uses reversed-Z; the CPU reference uses the same rays.

use crate::model::Camera;
use crate::shading::{V3, cross, normalize, scale, sub};

/// Orthonormal camera frame: `right`, `up`, `forward` (towards the target).
#[derive(Debug, Clone, Copy)]
pub struct Frame {
    pub right: V3,
    pub up: V3,
    pub forward: V3,
}

impl Camera {
    /// The camera turned `degrees` about the vertical (+Y) through its target, counter-clockwise
    /// seen from above: the orbit of walkthrough frames and benchmarks.
    pub fn orbited(&self, degrees: f32) -> Camera {
        let (s, c) = degrees.to_radians().sin_cos();
        let d = sub(self.position, self.target);
        Camera {
            position: [
                self.target[0] + (c * d[0] + s * d[2]),
                self.position[1],
                self.target[2] + (-s * d[0] + c * d[2]),
            ],
            ..*self
        }
    }

    pub fn aspect(&self) -> f32 {
        self.width as f32 / self.height.max(1) as f32
    }

    pub fn frame(&self) -> Frame {
        let forward = normalize(sub(self.target, self.position));
        let mut right = normalize(cross(forward, self.up));
        if right == [0.0; 3] {
            // Up parallel to the view direction: pick any perpendicular axis.
            right = normalize(cross(forward, [1.0, 0.0, 0.0]));
            if right == [0.0; 3] {
                right = normalize(cross(forward, [0.0, 0.0, 1.0]));
            }
        }
        let up = cross(right, forward);
        Frame { right, up, forward }
    }

    /// Unit direction of the primary ray through continuous image coordinates `(x, y)` (pixel
    /// `(i, j)` has its centre at `(i + 0.5, j + 0.5)`; row 0 is the top).
    pub fn ray_dir(&self, x: f32, y: f32) -> V3 {
        let f = self.frame();
        let t = (self.fov_y_deg.to_radians() * 0.5).tan();
        let sx = (2.0 * x / self.width as f32 - 1.0) * t * self.aspect();
        let sy = (1.0 - 2.0 * y / self.height as f32) * t;
        normalize([
            f.forward[0] + sx * f.right[0] + sy * f.up[0],
            f.forward[1] + sx * f.right[1] + sy * f.up[1],
            f.forward[2] + sx * f.right[2] + sy * f.up[2],
        ])
    }

    /// Column-major world → view matrix (view space looks down −Z).
    pub fn view_matrix(&self) -> [[f32; 4]; 4] {
        let f = self.frame();
        let p = self.position;
        let d = |a: V3| -(a[0] * p[0] + a[1] * p[1] + a[2] * p[2]);
        let b = scale(f.forward, -1.0);
        [
            [f.right[0], f.up[0], b[0], 0.0],
            [f.right[1], f.up[1], b[1], 0.0],
            [f.right[2], f.up[2], b[2], 0.0],
            [d(f.right), d(f.up), d(b), 1.0],
        ]
    }

    /// Column-major reversed-Z perspective projection with an infinite far plane (depth 1 at
    /// `near`, → 0 at infinity), wgpu clip conventions.
    pub fn projection_reversed_z(&self, near: f32) -> [[f32; 4]; 4] {
        let t = (self.fov_y_deg.to_radians() * 0.5).tan();
        let sy = 1.0 / t;
        let sx = sy / self.aspect();
        [
            [sx, 0.0, 0.0, 0.0],
            [0.0, sy, 0.0, 0.0],
            [0.0, 0.0, 0.0, -1.0],
            [0.0, 0.0, near, 0.0],
        ]
    }
}
