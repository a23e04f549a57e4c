//! `[sim.camera]`: the depth camera a run chooses (its rendered size, its
//! horizontal field of view, its range and the min-pool that makes the
//! image the network reads), from a named preset whose values are the
//! defaults of the keys set beside it.

use rotorhive_msg::{MAX_DEPTH_SIDE, MIN_DEPTH_SIDE};
use rotorhive_sim::CameraSpec;
use serde::{Deserialize, Serialize};

use crate::error::{Result, config_err};

/// The largest rendered side (pixels): the wgpu renderer's atlas holds
/// eight images a row in a texture of at most 8,192 texels.
pub const MAX_RENDER_SIDE: usize = 1024;

/// `sim.camera.preset`: a named camera.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum CameraPreset {
    /// The paper's: 32 × 32 pixels at 90 degrees, 20 m.
    #[default]
    Paper,
    /// A RealSense D455-like depth camera (Aerial Gym's preset): 480 × 270
    /// at 87 degrees, 15 m, min-pooled by 10 to the 48 × 27 the network
    /// reads.
    D455,
}

impl CameraPreset {
    /// Its values.
    pub fn spec(self) -> CameraSpec {
        match self {
            CameraPreset::Paper => CameraSpec::default(),
            CameraPreset::D455 => {
                CameraSpec { width: 480, height: 270, hfov_deg: 87.0, range: 15.0, pool: 10 }
            }
        }
    }
}

/// `[sim.camera]`: every key optional; a key left out takes the preset's
/// value (`paper` without one). `sim.depth_range` is another name of
/// `range` (setting both is refused).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CameraSection {
    /// The named camera whose values the other keys override.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub preset: Option<CameraPreset>,
    /// Rendered columns.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub width: Option<usize>,
    /// Rendered rows.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub height: Option<usize>,
    /// Horizontal field of view (degrees); the vertical one follows from
    /// the aspect (square pixels).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub hfov_deg: Option<f32>,
    /// Depth range (m): farther reads as the range, and depth is divided by it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub range: Option<f32>,
    /// Side of the blocks min-pooled into one pixel the network reads (each
    /// block's nearest depth, so that thin obstacles survive); it divides
    /// `width` and `height`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub pool: Option<usize>,
}

impl CameraSection {
    /// Whether no key is set (the section is then left out of a written config).
    pub fn is_unset(&self) -> bool {
        *self == Self::default()
    }

    /// The camera: the preset's values, each key set overriding its own.
    pub fn spec(&self) -> CameraSpec {
        let p = self.preset.unwrap_or_default().spec();
        CameraSpec {
            width: self.width.unwrap_or(p.width),
            height: self.height.unwrap_or(p.height),
            hfov_deg: self.hfov_deg.unwrap_or(p.hfov_deg),
            range: self.range.unwrap_or(p.range),
            pool: self.pool.unwrap_or(p.pool),
        }
    }

    /// Checks the camera the section gives: sizes the renderers and the
    /// network take, each refused by name with the nearest that work.
    pub fn validate(&self) -> Result<()> {
        let c = self.spec();
        for (key, side) in [("sim.camera.width", c.width), ("sim.camera.height", c.height)] {
            if !(1..=MAX_RENDER_SIDE).contains(&side) {
                config_err!("key `{key}` must be 1 to {MAX_RENDER_SIDE} pixels, got {side}");
            }
        }
        if !(c.hfov_deg.is_finite() && c.hfov_deg > 0.0 && c.hfov_deg < 180.0) {
            config_err!(
                "key `sim.camera.hfov_deg` must lie in (0, 180) degrees, got {}",
                c.hfov_deg
            );
        }
        // Square pixels: a tall image at a wide angle sees all round.
        if c.tan_v() >= 100.0 {
            config_err!(
                "key `sim.camera.hfov_deg` of {} with a {} x {} image gives a vertical field \
                 of view of 180 degrees or more",
                c.hfov_deg,
                c.width,
                c.height
            );
        }
        if !(c.range.is_finite() && c.range > 0.0) {
            config_err!("key `sim.camera.range` must be positive, got {}", c.range);
        }
        if c.pool == 0 {
            config_err!("key `sim.camera.pool` must be 1 or more, got 0");
        }
        for (key, side) in [("sim.camera.width", c.width), ("sim.camera.height", c.height)] {
            if !side.is_multiple_of(c.pool) {
                let below = side / c.pool * c.pool;
                config_err!(
                    "key `{key}` ({side}) is not a multiple of `sim.camera.pool` ({}): {} or {} is",
                    c.pool,
                    below.max(c.pool),
                    below + c.pool
                );
            }
            let seen = side / c.pool;
            if !(MIN_DEPTH_SIDE..=MAX_DEPTH_SIDE).contains(&seen) {
                let near = seen.clamp(MIN_DEPTH_SIDE, MAX_DEPTH_SIDE) * c.pool;
                config_err!(
                    "key `{key}` ({side}) with `sim.camera.pool` {} gives the network {seen} \
                     pixels; it reads {MIN_DEPTH_SIDE} to {MAX_DEPTH_SIDE} a side ({key} = \
                     {near} would do)",
                    c.pool
                );
            }
        }
        Ok(())
    }

    /// The section as a checkpoint's header names it (`camera`): the
    /// resolved values, `WIDTHxHEIGHT hfov DEG range M pool P`.
    pub fn name(&self) -> String {
        camera_name(&self.spec())
    }
}

/// A camera as a checkpoint's header names it.
pub fn camera_name(c: &CameraSpec) -> String {
    format!("{}x{} hfov {} range {} pool {}", c.width, c.height, c.hfov_deg, c.range, c.pool)
}

/// A camera from [`camera_name`]'s form; `None` where the text is not one.
pub fn parse_camera(text: &str) -> Option<CameraSpec> {
    let p: Vec<&str> = text.split(' ').collect();
    let [size, "hfov", hfov, "range", range, "pool", pool] = p[..] else {
        return None;
    };
    let (w, h) = size.split_once('x')?;
    Some(CameraSpec {
        width: w.parse().ok()?,
        height: h.parse().ok()?,
        hfov_deg: hfov.parse().ok()?,
        range: range.parse().ok()?,
        pool: pool.parse().ok()?,
    })
}

/// The camera a checkpoint was trained with: its header's `camera`
/// (written for a camera other than the paper's), else the paper's;
/// checked against the frames its network reads.
pub fn checkpoint_camera(path: &std::path::Path) -> Result<CameraSpec> {
    let bad =
        |m: String| crate::ConfigError::Invalid(format!("checkpoint {}: {m}", path.display()));
    let entry = rotorhive_model::checkpoint_entry(path, "camera")?;
    let camera = match entry {
        None => CameraSpec::default(),
        Some(text) => parse_camera(&text).ok_or_else(|| {
            bad(format!("header entry `camera` is {text:?}, not `WxH hfov DEG range M pool P`"))
        })?,
    };
    let depth = rotorhive_model::checkpoint_shapes(path)?.depth;
    if camera.observed_depth() != depth || camera.pool == 0 {
        return Err(bad(format!(
            "header entry `camera` ({}) does not give the {} x {} frames its network reads",
            camera_name(&camera),
            depth[0],
            depth[1]
        )));
    }
    Ok(camera)
}

/// `--set` keys that give a config the camera `c`.
pub fn camera_sets(c: &CameraSpec) -> Vec<String> {
    vec![
        format!("sim.camera.width={}", c.width),
        format!("sim.camera.height={}", c.height),
        format!("sim.camera.hfov_deg={:?}", c.hfov_deg),
        format!("sim.camera.range={:?}", c.range),
        format!("sim.camera.pool={}", c.pool),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_preset_gives_the_defaults_and_keys_override_them() {
        assert_eq!(CameraSection::default().spec(), CameraSpec::default());
        let d455 = CameraSection { preset: Some(CameraPreset::D455), ..Default::default() };
        let c = d455.spec();
        assert_eq!((c.width, c.height, c.pool, c.observed_depth()), (480, 270, 10, [27, 48]));
        d455.validate().unwrap();
        let wider = CameraSection { hfov_deg: Some(120.0), range: Some(30.0), ..d455.clone() };
        assert_eq!(
            (wider.spec().hfov_deg, wider.spec().range, wider.spec().width),
            (120.0, 30.0, 480)
        );
        assert_eq!(parse_camera(&wider.name()), Some(wider.spec()));
        assert_eq!(parse_camera("32x32 hfov 90"), None);
    }

    #[test]
    fn a_checkpoints_camera_is_read_and_a_forged_one_refused_by_name() {
        use rotorhive_model::{Device, Layers, PolicyNet, Shapes};
        let dir = std::env::temp_dir().join(format!("rotorhive-camera-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("c.safetensors");
        let save = |shapes: Shapes, camera: Option<&str>| {
            let net = PolicyNet::new(shapes, Layers::DEFAULT, None, 1, &Device::Cpu).unwrap();
            let tags: Vec<(&str, String)> =
                camera.map(|c| ("camera", c.to_string())).into_iter().collect();
            net.save(&path, &tags).unwrap();
        };
        save(Shapes::PAPER, None);
        assert_eq!(checkpoint_camera(&path).unwrap(), CameraSpec::default());
        let wide = CameraSection { preset: Some(CameraPreset::D455), ..Default::default() };
        save(Shapes::PAPER.with_depth(wide.spec().observed_depth()), Some(&wide.name()));
        assert_eq!(checkpoint_camera(&path).unwrap(), wide.spec());
        for (shapes, forged, says) in [
            (Shapes::PAPER, "a camera", "not `WxH hfov DEG range M pool P`"),
            (Shapes::PAPER, "64x64 hfov 90 range 20 pool 1", "does not give the 32 x 32 frames"),
            (Shapes::PAPER, "32x32 hfov 90 range 20 pool 0", "does not give the 32 x 32 frames"),
        ] {
            save(shapes, Some(forged));
            let e = checkpoint_camera(&path).unwrap_err().to_string();
            assert!(e.contains("c.safetensors") && e.contains(says), "{forged}: {e}");
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn sizes_the_network_cannot_read_are_refused_with_ones_it_can() {
        let set = |width, height, pool| CameraSection {
            width: Some(width),
            height: Some(height),
            pool: Some(pool),
            ..Default::default()
        };
        for (c, says) in [
            (
                set(100, 64, 3),
                "`sim.camera.width` (100) is not a multiple of `sim.camera.pool` (3): 99 or 102",
            ),
            (
                set(8, 32, 1),
                "gives the network 8 pixels; it reads 12 to 256 a side (sim.camera.width = 12",
            ),
            (
                set(128, 40, 4),
                "`sim.camera.height` (40) with `sim.camera.pool` 4 gives the network 10 pixels",
            ),
            (set(2048, 32, 1), "`sim.camera.width` must be 1 to 1024"),
            (set(64, 64, 0), "`sim.camera.pool` must be 1 or more"),
        ] {
            let e = c.validate().unwrap_err().to_string();
            assert!(e.contains(says), "{e}");
        }
        set(128, 128, 4).validate().unwrap();
        set(64, 48, 1).validate().unwrap();
        let e =
            CameraSection { hfov_deg: Some(180.0), ..Default::default() }.validate().unwrap_err();
        assert!(e.to_string().contains("sim.camera.hfov_deg"), "{e}");
    }
}
