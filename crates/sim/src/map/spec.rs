//! The camera's map's settings (`[sim.map]`): how the student reads it
//! and what it holds, checked by key.

/// How the map enters the observation (`sim.map.encoding`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MapEncoding {
    /// No map: the observation is depth, velocity (and goal) as ever.
    #[default]
    None,
    /// An egocentric window of `window × window` cells turned to the
    /// heading, the drone a quarter of the way from its back edge; each
    /// cell 0 (unknown), 1/3 (free), 2/3 (wall) or 1 (obstacle).
    Grid,
    /// `rays` distances cast through the map over 360 degrees from the
    /// heading, counter-clockwise, to the first obstacle or wall, then as
    /// many to the first unknown cell; each divided by `ray_range_m` (1:
    /// nothing within it).
    Rays,
}

impl MapEncoding {
    /// Its name in configs (`sim.map.encoding`).
    pub fn name(self) -> &'static str {
        match self {
            MapEncoding::None => "none",
            MapEncoding::Grid => "grid",
            MapEncoding::Rays => "rays",
        }
    }
}

/// The map's settings (`[sim.map]`; off by default).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MapSpec {
    /// How the student reads the map (`none`: no map).
    pub encoding: MapEncoding,
    /// Side of one cell (m).
    pub cell_m: f32,
    /// Cells a side of the `grid` encoding's window.
    pub window: usize,
    /// Directions of the `rays` encoding.
    pub rays: usize,
    /// How far the `rays` encoding looks (m).
    pub ray_range_m: f32,
    /// How long a sighting of an obstacle is kept (s; 0: the whole
    /// episode). With it, a ray that crosses a cell clears an earlier
    /// sighting there (an obstacle that moved away); without it sightings
    /// stay (a still obstacle never leaves).
    pub keep_s: f32,
    /// Rows of each frame read, about its middle (0: every row): the band
    /// at the flight's altitude.
    pub band: usize,
    /// The `rays` encoding's directions cast again, once for each of these
    /// times ahead (s), through the seen movers (`[sim.tracks]`) as their
    /// tracks alone predict them then (`Track::predicted`, as the map's
    /// planner takes them): `rays` distances each, after the map's (empty:
    /// none; without a map, none either). The same information as the
    /// tracks, in the rays' form.
    pub movers_ahead_s: Vec<f32>,
}

impl Default for MapSpec {
    fn default() -> Self {
        Self {
            encoding: MapEncoding::None,
            cell_m: 0.5,
            window: 16,
            rays: 36,
            ray_range_m: 10.0,
            keep_s: 0.0,
            band: 4,
            movers_ahead_s: Vec::new(),
        }
    }
}

impl MapSpec {
    /// Whether the settings are the defaults (no map): a config writes no
    /// `[sim.map]` then.
    pub fn is_off(&self) -> bool {
        *self == Self::default()
    }

    /// Whether the observation holds the map.
    pub fn enabled(&self) -> bool {
        self.encoding != MapEncoding::None
    }

    /// Floats the map adds to an observation.
    pub fn floats(&self) -> usize {
        match self.encoding {
            MapEncoding::None => 0,
            MapEncoding::Grid => self.window * self.window,
            MapEncoding::Rays => (2 + self.movers_ahead_s.len()) * self.rays,
        }
    }

    /// How far from the camera a frame's crossed cells are marked free (m):
    /// as far as the encoding reads (the rays' range, the window's far
    /// corner). Farther cells are marked when the drone comes nearer; hits
    /// are marked at any distance.
    pub fn reach(&self) -> f32 {
        match self.encoding {
            MapEncoding::Rays => self.ray_range_m,
            _ => self.window as f32 * self.cell_m * 0.9,
        }
    }

    /// Checks the ranges; the key (under `[sim.map]`) and what is wrong.
    pub fn validate(&self) -> Result<(), (&'static str, String)> {
        for (key, v, lo, hi) in [
            ("cell_m", self.cell_m, 0.05, 5.0),
            ("ray_range_m", self.ray_range_m, 0.5, 100.0),
            ("keep_s", self.keep_s, 0.0, MAX_KEEP_S),
        ] {
            if !(lo..=hi).contains(&v) {
                return Err((key, format!("must lie in [{lo}, {hi}], got {v}")));
            }
        }
        if !(2..=32).contains(&self.window) {
            return Err(("window", format!("must be 2 to 32 cells, got {}", self.window)));
        }
        if !(4..=360).contains(&self.rays) {
            return Err(("rays", format!("must be 4 to 360 directions, got {}", self.rays)));
        }
        if self.band > 1024 {
            return Err(("band", format!("must be 0 (every row) to 1024 rows, got {}", self.band)));
        }
        let ahead = &self.movers_ahead_s;
        // Without a map (`none`, as an evaluation or a user turns it off)
        // the times ahead are read by nothing; the grid has no rays.
        if !ahead.is_empty() && self.encoding == MapEncoding::Grid {
            return Err(("movers_ahead_s", "needs `encoding = \"rays\"`".into()));
        }
        if ahead.len() > MAX_AHEAD || !ahead.iter().all(|s| (0.0..=MAX_AHEAD_S).contains(s)) {
            return Err((
                "movers_ahead_s",
                format!(
                    "must hold at most {MAX_AHEAD} times in [0, {MAX_AHEAD_S}] s, got {ahead:?}"
                ),
            ));
        }
        if self.floats() > rotorhive_msg::MAX_MAP_FLOATS {
            return Err((
                "encoding",
                format!(
                    "gives {} floats, more than {}",
                    self.floats(),
                    rotorhive_msg::MAX_MAP_FLOATS
                ),
            ));
        }
        Ok(())
    }
}

/// The most times ahead of `movers_ahead_s`, and the furthest (s).
pub const MAX_AHEAD: usize = 8;
pub const MAX_AHEAD_S: f32 = 30.0;

/// The longest a sighting may be kept (s): stamps count frames modulo
/// the map's 253 stamps, and an age must stay under it.
pub const MAX_KEEP_S: f32 = 240.0;
