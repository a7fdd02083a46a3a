//! The built-in scenes, written in the scene file format so they double as examples; usable
//! by name wherever a scene file is.

/// Names of the built-in scenes.
pub const NAMES: &[&str] = &["demo", "beech", "catalpa", "canopy"];

/// TOML source of built-in scene `name`.
pub fn source(name: &str) -> Option<&'static str> {
    match name {
        "demo" => Some(DEMO),
        "beech" => Some(BEECH),
        "catalpa" => Some(CATALPA),
        "canopy" => Some(CANOPY),
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
        _ => None,
    }
}

const DEMO: &str = r#"# A small mixed forest that renders quickly.
name = "demo"

[[models]]
name = "maple"
species = "red_maple"

[[models]]
name = "pine"
species = "pine"

[[models]]
name = "rose"
species = "dogrose"

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

[ground]
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
