//! The camera and the lights of a render, parsed from the command line's
//! `--camera`, `--light` and `--point-light` values.

use super::*;
use crate::math;

/// A pinhole camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub eye: [f32; 3],
    pub target: [f32; 3],
    pub up: [f32; 3],
    /// Vertical field of view in degrees.
    pub fov: f32,
}

impl Camera {
    /// Parses `ex,ey,ez,tx,ty,tz,ux,uy,uz,fov`.
    pub fn parse(s: &str) -> Result<Camera> {
        let bad = || {
            Error::Config(format!(
                "--camera '{s}': expected eye,target,up,fov as 10 numbers"
            ))
        };
        let v: Vec<f32> = s
            .split(',')
            .map(|x| x.trim().parse::<f32>())
            .collect::<std::result::Result<_, _>>()
            .map_err(|_| bad())?;
        if v.len() != 10 {
            return Err(bad());
        }
        let cam = Camera {
            eye: [v[0], v[1], v[2]],
            target: [v[3], v[4], v[5]],
            up: [v[6], v[7], v[8]],
            fov: v[9],
        };
        cam.check()
            .map_err(|why| Error::Config(format!("--camera '{s}': {why}")))?;
        Ok(cam)
    }

    /// Checks the numbers: all finite, a field of view in 1..179 degrees,
    /// an eye apart from the target and an up not along the view.
    pub(super) fn check(&self) -> std::result::Result<(), String> {
        let names = ["eye", "target", "up"];
        for (name, v) in names.iter().zip([self.eye, self.target, self.up]) {
            if let Some(k) = v.iter().position(|x| !x.is_finite()) {
                return Err(format!(
                    "the {name}'s {} coordinate is {}: every number must be finite",
                    ["x", "y", "z"][k],
                    v[k]
                ));
            }
        }
        if !(1.0..179.0).contains(&self.fov) {
            return Err(format!(
                "the field of view {} must be a finite number of degrees in 1..179",
                self.fov
            ));
        }
        let cam = self;
        let f = unit_or(Vec3::from(cam.target) - Vec3::from(cam.eye), Vec3::ZERO);
        if f.length_squared() < 0.5 || f.cross(unit_or(cam.up.into(), Vec3::ZERO)).length() < 1e-4 {
            return Err("the eye must differ from the target and up must not be along the view".into());
        }
        Ok(())
    }

    /// A three-quarter view framing the given positions.
    pub fn framing(positions: &[[f32; 3]]) -> Camera {
        let (c, radius) = bounds(positions);
        let d = unit_or(Vec3::new(0.8, 0.45, 1.0), Vec3::ZERO);
        let dist = radius / math::tan(20f32.to_radians());
        Camera {
            eye: (Vec3::from(c) + d * dist).to_array(),
            target: c,
            up: [0.0, 1.0, 0.0],
            fov: 42.0,
        }
    }

    /// The unit axis from the target towards the eye.
    pub fn axis(&self) -> [f32; 3] {
        unit_or(Vec3::from(self.eye) - Vec3::from(self.target), Vec3::ZERO).to_array()
    }
}

/// Bounding-box centre and half diagonal.
pub(super) fn bounds(positions: &[[f32; 3]]) -> ([f32; 3], f32) {
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for p in positions {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    if positions.is_empty() {
        return ([0.0; 3], 1.0);
    }
    let (lo, hi) = (Vec3::from(lo), Vec3::from(hi));
    (((lo + hi) / 2.0).to_array(), 0.5 * (hi - lo).length())
}

/// A light source.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Light {
    /// Parallel light; `direction` points towards the light (world space,
    /// any length but zero).
    Directional { direction: [f32; 3], intensity: f32 },
    /// A point light with inverse-square falloff, normalised so that it gives
    /// `intensity` at the distance of the mesh's bounding-box centre.
    Point { position: [f32; 3], intensity: f32 },
}

impl Default for Light {
    /// The default directional light, [`DEFAULT_LIGHT`] at intensity 1.
    fn default() -> Self {
        Light::directional(DEFAULT_LIGHT)
    }
}

/// Parses `n` comma-separated finite numbers for `flag`, `n` in `counts`.
fn numbers(flag: &str, s: &str, what: &str, counts: &[usize]) -> Result<Vec<f32>> {
    let bad = || Error::Config(format!("{flag} '{s}': expected {what}"));
    let v: Vec<f32> = s
        .split(',')
        .map(|x| x.trim().parse::<f32>())
        .collect::<std::result::Result<_, _>>()
        .map_err(|_| bad())?;
    if !counts.contains(&v.len()) || v.iter().any(|x| !x.is_finite()) {
        return Err(bad());
    }
    Ok(v)
}

impl Light {
    /// A directional light of intensity 1 towards `direction`.
    pub fn directional(direction: [f32; 3]) -> Light {
        Light::Directional {
            direction,
            intensity: 1.0,
        }
    }

    /// Parses `--light x,y,z[,intensity]` (towards the light, world space).
    pub fn parse_directional(s: &str) -> Result<Light> {
        let what = "x,y,z[,intensity]: a nonzero direction towards the light and an intensity ≥ 0";
        let v = numbers("--light", s, what, &[3, 4])?;
        let direction = [v[0], v[1], v[2]];
        let intensity = v.get(3).copied().unwrap_or(1.0);
        if Vec3::from(direction).length_squared() < 1e-12 || intensity < 0.0 {
            return Err(Error::Config(format!("--light '{s}': expected {what}")));
        }
        Ok(Light::Directional { direction, intensity })
    }

    /// Parses `--point-light x,y,z[,intensity]` (world-space position).
    pub fn parse_point(s: &str) -> Result<Light> {
        let what = "x,y,z[,intensity]: a position and an intensity ≥ 0";
        let v = numbers("--point-light", s, what, &[3, 4])?;
        let intensity = v.get(3).copied().unwrap_or(1.0);
        if intensity < 0.0 {
            return Err(Error::Config(format!("--point-light '{s}': expected {what}")));
        }
        Ok(Light::Point {
            position: [v[0], v[1], v[2]],
            intensity,
        })
    }

    /// The light turned by `angle` radians about the camera's view axis (the
    /// line through the target towards the eye): a directional light keeps
    /// its angle to the axis, a point light its distance to the axis line.
    pub fn orbit(&self, camera: &Camera, angle: f32) -> Light {
        let axis = Vec3::from(camera.axis());
        let target = Vec3::from(camera.target);
        match *self {
            Light::Directional { direction, intensity } => Light::Directional {
                direction: rotate(direction.into(), axis, angle).to_array(),
                intensity,
            },
            Light::Point { position, intensity } => {
                let r = rotate(Vec3::from(position) - target, axis, angle);
                Light::Point {
                    position: (r + target).to_array(),
                    intensity,
                }
            }
        }
    }
}

/// Rodrigues' rotation of `v` by `angle` about the unit `axis`.
fn rotate(v: Vec3, axis: Vec3, angle: f32) -> Vec3 {
    let (s, c) = math::sin_cos(angle);
    let kxv = axis.cross(v);
    let kdv = axis.dot(v);
    v * c + kxv * s + axis * kdv * (1.0 - c)
}
