//! The built-in scenes, written in the scene file format so they double as examples; usable
//! by name wherever a scene file is.

/// Names of the built-in scenes.
pub const NAMES: &[&str] = &[
    "demo",
    "beech",
    "catalpa",
    "canopy",
    "shade",
    "cloud",
    "teapot",
    "demo_cloud",
    "woodland",
];

/// TOML source of built-in scene `name`.
pub fn source(name: &str) -> Option<&'static str> {
    match name {
        "demo" => Some(DEMO),
        "beech" => Some(BEECH),
        "catalpa" => Some(CATALPA),
        "canopy" => Some(CANOPY),
        "shade" => Some(SHADE),
        "cloud" => Some(CLOUD),
        "teapot" => Some(TEAPOT),
        "demo_cloud" => Some(DEMO_CLOUD),
        "woodland" => Some(WOODLAND),
        _ => None,
    }
}

/// One-line description of built-in scene `name`.
pub fn describe(name: &str) -> Option<&'static str> {
    match name {
        "demo" => Some("small mixed forest (maples, pines, dogroses); quick to render; the default of `sylva render`"),
        "beech" => Some("paper 000 Table 2: 962 trees of 5 species, about 270 M instanced triangles, 896×448"),
        "catalpa" => Some("paper 004 Fig. 3 top: one southern catalpa, 512×512"),
        "canopy" => Some("paper 004 Fig. 3 bottom: a dense canopy of 5 species, about 100 M instanced triangles, 512×512"),
        "shade" => Some("paper 004 Fig. 2: a big beech shading one of two small catalpas (the coarse global grid's test scene)"),
        "cloud" => Some("paper 002 Fig. 1: a 256×128×128 cumulus lit by LB over a sky, 640×360"),
        "teapot" => Some("paper 002 Figs. 4-5: the Newell teapot in PMMA, LB glow against conventional lighting, 512×384"),
        "demo_cloud" => Some("the demo forest under a fair-weather cumulus (clouds in forest scenes, 000 Fig. 3)"),
        "woodland" => Some("a billion triangles: 3,900 trees of 6 species over 480 × 240 m, about 1.09 G instanced triangles, 896×448"),
        _ => None,
    }
}

/// The demo's plants and their placement, shared by `demo` and `demo_cloud`.
macro_rules! demo_forest {
    () => {
        r#"[[models]]
name = "maple"
species = "red_maple"

[[models]]
name = "pine"
species = "pine"

[[models]]
name = "rose"
species = "dogrose"
preset = "dogrose"

[[instances]]
model = "maple"
position = [0.0, 0.0, 0.0]
rotation = 20.0

[[instances]]
model = "maple"
count = 2
area = { min = [-16.0, -6.0], max = [16.0, 14.0] }
min_spacing = 9.0
scale_jitter = 0.1
seed = 1

[[instances]]
model = "pine"
count = 3
area = { min = [-20.0, 4.0], max = [20.0, 18.0] }
min_spacing = 9.0
scale_jitter = 0.1
seed = 2

[[instances]]
model = "rose"
count = 6
area = { min = [-12.0, -12.0], max = [12.0, 0.0] }
min_spacing = 3.5
scale_jitter = 0.2
seed = 3

"#
    };
}

const DEMO: &str = concat!(
    r#"# A small mixed forest that renders quickly.
name = "demo"

"#,
    demo_forest!(),
    r#"[ground]
size = [80.0, 80.0]
color = [0.16, 0.14, 0.08]

[sun]
elevation = 50.0
azimuth = 30.0

[sky]
color = [0.55, 0.70, 0.95]

[camera]
position = [0.0, 5.0, -34.0]
look_at = [0.0, 6.0, 0.0]
fov = 50.0
resolution = [480, 270]
rays_per_pixel = 1

[lb]
grid = 64
preset = "leaf"
"#
);

const DEMO_CLOUD: &str = concat!(
    r#"# The demo forest under a fair-weather cumulus (000 Fig. 3's forest has synthetic clouds).
name = "demo_cloud"

"#,
    demo_forest!(),
    r#"# A cumulus 1.5 km behind the trees: 128×64×64 sites of 9.45 m; its base (the
# condensation level) 300 m up.
[[media]]
name = "cumulus"
generator = "cumulus"
grid = [128, 64, 64]
size = 1200.0
seed = 3
position = [150.0, 0.0, 1500.0]
preset = "cloud"

[ground]
size = [80.0, 80.0]
color = [0.16, 0.14, 0.08]

[sun]
elevation = 40.0
azimuth = 240.0

[sky]
color = [0.40, 0.58, 0.92]

[camera]
position = [0.0, 4.0, -34.0]
look_at = [0.0, 9.0, 0.0]
fov = 50.0
resolution = [480, 270]
rays_per_pixel = 1

[lb]
grid = 64
preset = "leaf"
"#
);

const CLOUD: &str = r#"# Paper 002 Fig. 1: a cumulus lit by LB (cloud preset: g 0.9, σ_a 0.008, σ_s 0.792) over a
# sky. 256×128×128 sites of 12 m: the cloud field is 3 km wide, its base 300 m up.
name = "cloud"

[[media]]
name = "cumulus"
generator = "cumulus"
grid = [256, 128, 128]
seed = 1
position = [0.0, 0.0, 0.0]
preset = "cloud"

[ground]
enabled = false

# The sun from the left, a little behind the cloud; a clear sky's radiance is about a tenth
# of the sun's irradiance (sylva's units: the sun lights a white surface facing it to 1).
[sun]
elevation = 35.0
azimuth = 160.0

[sky]
color = [0.12, 0.20, 0.40]

[camera]
position = [-500.0, 200.0, -2700.0]
look_at = [0.0, 640.0, 0.0]
fov = 42.0
resolution = [640, 360]
rays_per_pixel = 1

[lb]
preset = "cloud"
"#;

const TEAPOT: &str = r#"# Paper 002 Figs. 4-5: the Newell teapot in PMMA (002 Table 2), lit by LB (render with
# --mode all: full is LB lighting, ambient the conventional lighting of Fig. 5).
name = "teapot"

[[models]]
name = "teapot"
shape = "teapot"
preset = "pmma"

[[instances]]
model = "teapot"
position = [0.0, 0.0, 0.0]

[ground]
size = [30.0, 30.0]
color = [0.30, 0.30, 0.30]

[sun]
elevation = 35.0
azimuth = 70.0

[sky]
color = [0.55, 0.70, 0.95]

[camera]
position = [1.5, 4.8, -10.5]
look_at = [0.25, 1.45, 0.0]
fov = 36.0
resolution = [512, 384]
rays_per_pixel = 1

[lb]
grid = 128
preset = "pmma"
"#;

const BEECH: &str = r#"# Paper 000 Table 2 / Fig. 3a: the beech tree scene.
name = "beech"

[[models]]
name = "red_maple"
species = "red_maple"

[[models]]
name = "ohio_buckeye"
species = "ohio_buckeye"

[[models]]
name = "paper_birch"
species = "paper_birch"

[[models]]
name = "southern_catalpa"
species = "southern_catalpa"

[[models]]
name = "american_beech"
species = "american_beech"

# The beeches and the largest trees first, so the spacing leaves room for them.
[[instances]]
model = "american_beech"
count = 168
area = { min = [-120.0, -60.0], max = [120.0, 60.0] }
min_spacing = 3.5
scale_jitter = 0.15
seed = 11

[[instances]]
model = "paper_birch"
count = 291
area = { min = [-120.0, -60.0], max = [120.0, 60.0] }
min_spacing = 3.5
scale_jitter = 0.15
seed = 12

[[instances]]
model = "ohio_buckeye"
count = 285
area = { min = [-120.0, -60.0], max = [120.0, 60.0] }
min_spacing = 3.5
scale_jitter = 0.15
seed = 13

[[instances]]
model = "southern_catalpa"
count = 206
area = { min = [-120.0, -60.0], max = [120.0, 60.0] }
min_spacing = 3.5
scale_jitter = 0.15
seed = 14

[[instances]]
model = "red_maple"
count = 12
area = { min = [-120.0, -60.0], max = [120.0, 60.0] }
min_spacing = 3.5
scale_jitter = 0.15
seed = 15

[ground]
size = [300.0, 180.0]
color = [0.16, 0.14, 0.08]

[sun]
elevation = 45.0
azimuth = 60.0

[sky]
color = [0.55, 0.70, 0.95]

[camera]
position = [0.0, 14.0, -95.0]
look_at = [0.0, 8.0, 0.0]
fov = 40.0
resolution = [896, 448]
rays_per_pixel = 1

[lb]
grid = 128
preset = "leaf"
"#;

const CATALPA: &str = r#"# Paper 004 Fig. 3 top: a single southern catalpa.
name = "catalpa"

[[models]]
name = "catalpa"
species = "southern_catalpa"

[[instances]]
model = "catalpa"
position = [0.0, 0.0, 0.0]

[ground]
size = [60.0, 60.0]
color = [0.16, 0.14, 0.08]

[sun]
elevation = 50.0
azimuth = 30.0

[sky]
color = [0.55, 0.70, 0.95]

[camera]
position = [0.0, 6.0, -26.0]
look_at = [0.0, 6.0, 0.0]
fov = 40.0
resolution = [512, 512]
rays_per_pixel = 1

[lb]
grid = 128
preset = "leaf"
"#;

const CANOPY: &str = r#"# Paper 004 Fig. 3 bottom: a dense canopy of five species (about 100 M instanced triangles).
name = "canopy"

[[models]]
name = "red_maple"
species = "red_maple"

[[models]]
name = "ohio_buckeye"
species = "ohio_buckeye"

[[models]]
name = "paper_birch"
species = "paper_birch"

[[models]]
name = "southern_catalpa"
species = "southern_catalpa"

[[models]]
name = "american_beech"
species = "american_beech"

[[instances]]
model = "american_beech"
count = 75
area = { min = [-40.0, -40.0], max = [40.0, 40.0] }
min_spacing = 3.0
scale_jitter = 0.15
seed = 21

[[instances]]
model = "paper_birch"
count = 80
area = { min = [-40.0, -40.0], max = [40.0, 40.0] }
min_spacing = 3.0
scale_jitter = 0.15
seed = 22

[[instances]]
model = "ohio_buckeye"
count = 120
area = { min = [-40.0, -40.0], max = [40.0, 40.0] }
min_spacing = 3.0
scale_jitter = 0.15
seed = 23

[[instances]]
model = "southern_catalpa"
count = 70
area = { min = [-40.0, -40.0], max = [40.0, 40.0] }
min_spacing = 3.0
scale_jitter = 0.15
seed = 24

[[instances]]
model = "red_maple"
count = 20
area = { min = [-40.0, -40.0], max = [40.0, 40.0] }
min_spacing = 3.0
scale_jitter = 0.15
seed = 25

[ground]
size = [100.0, 100.0]
color = [0.16, 0.14, 0.08]

[sun]
elevation = 60.0
azimuth = 45.0

[sky]
color = [0.55, 0.70, 0.95]

[camera]
position = [0.0, 40.0, -62.0]
look_at = [0.0, 10.0, 0.0]
fov = 45.0
resolution = [512, 512]
rays_per_pixel = 1

[lb]
grid = 128
preset = "leaf"
"#;

const WOODLAND: &str = r#"# A billion triangles (issue 28 item 5): 3,900 trees of six species over 480 × 240 m.
name = "woodland"

[[models]]
name = "red_maple"
species = "red_maple"

[[models]]
name = "ohio_buckeye"
species = "ohio_buckeye"

[[models]]
name = "paper_birch"
species = "paper_birch"

[[models]]
name = "southern_catalpa"
species = "southern_catalpa"

[[models]]
name = "american_beech"
species = "american_beech"

[[models]]
name = "pine"
species = "pine"

[[instances]]
model = "american_beech"
count = 700
area = { min = [-240.0, -120.0], max = [240.0, 120.0] }
min_spacing = 3.5
scale_jitter = 0.15
seed = 31

[[instances]]
model = "paper_birch"
count = 1100
area = { min = [-240.0, -120.0], max = [240.0, 120.0] }
min_spacing = 3.5
scale_jitter = 0.15
seed = 32

[[instances]]
model = "pine"
count = 300
area = { min = [-240.0, -120.0], max = [240.0, 120.0] }
min_spacing = 3.5
scale_jitter = 0.15
seed = 33

[[instances]]
model = "ohio_buckeye"
count = 900
area = { min = [-240.0, -120.0], max = [240.0, 120.0] }
min_spacing = 3.5
scale_jitter = 0.15
seed = 34

[[instances]]
model = "southern_catalpa"
count = 700
area = { min = [-240.0, -120.0], max = [240.0, 120.0] }
min_spacing = 3.5
scale_jitter = 0.15
seed = 35

[[instances]]
model = "red_maple"
count = 200
area = { min = [-240.0, -120.0], max = [240.0, 120.0] }
min_spacing = 3.5
scale_jitter = 0.15
seed = 36

[ground]
size = [560.0, 320.0]
color = [0.16, 0.14, 0.08]

[sun]
elevation = 45.0
azimuth = 60.0

[sky]
color = [0.55, 0.70, 0.95]

[camera]
position = [0.0, 40.0, -190.0]
look_at = [0.0, 6.0, 0.0]
fov = 40.0
resolution = [896, 448]
rays_per_pixel = 1

[lb]
grid = 128
preset = "leaf"
"#;

/// One tree of built-in species `species` at the origin ([`single_tree`]), built.
pub fn species_scene(species: &str) -> Result<sylva_geom::Scene, crate::SceneError> {
    let text = single_tree(species)
        .ok_or_else(|| crate::SceneError::NoSceneOrSpecies(species.to_string()))?;
    crate::SceneDesc::parse(&text, &format!("species '{species}'"), None)?.build()
}

/// Scene TOML of one tree of built-in species `species` at the origin (the camera framing a
/// tree of about 15 m, the LB grid at 128), or `None` when there is no such species: for
/// commands that study a single tree (`sylva spp trees red_maple`).
pub fn single_tree(species: &str) -> Option<String> {
    let s = sylva_grow::Species::builtin(species)?;
    Some(format!(
        r#"# One {display} at the origin.
name = "{name}"

[[models]]
name = "{name}"
species = "{name}"

[[instances]]
model = "{name}"
position = [0.0, 0.0, 0.0]

[ground]
size = [60.0, 60.0]
color = [0.16, 0.14, 0.08]

[camera]
position = [0.0, 6.0, -30.0]
look_at = [0.0, 7.0, 0.0]
fov = 40.0
resolution = [512, 512]

[lb]
grid = 128
preset = "leaf"
"#,
        display = s.display_name,
        name = s.name,
    ))
}

const SHADE: &str = r#"# Paper 004 Fig. 2: one big tree shading one of two smaller instances of another model.
# The sun stands to the right (towards +x, a little towards +z), low; the small catalpa on
# the left lies in the beech's shade, the one in front does not.
name = "shade"

[[models]]
name = "beech"
species = "american_beech"

[[models]]
name = "catalpa"
species = "southern_catalpa"

[[instances]]
model = "beech"
position = [6.0, 0.0, 0.0]
rotation = 0.0

# In the beech's shade: on the line from the beech's crown away from the sun.
[[instances]]
model = "catalpa"
position = [-4.0, 0.0, -3.6]
rotation = 30.0
scale = 0.55

# In the open, nearer the camera: nothing stands between it and the sun.
[[instances]]
model = "catalpa"
position = [-8.0, 0.0, 20.0]
rotation = 150.0
scale = 0.55

[ground]
size = [80.0, 80.0]
color = [0.16, 0.14, 0.08]

[sun]
elevation = 30.0
azimuth = 20.0

[sky]
color = [0.55, 0.70, 0.95]

[camera]
position = [0.0, 8.0, 38.0]
look_at = [0.0, 6.0, 0.0]
fov = 45.0
resolution = [512, 384]
rays_per_pixel = 1

[lb]
grid = 128
preset = "leaf"
"#;
