//! The page: HTML, script and style, compiled into the binary (plain files, no build step;
//! crates/sylva-view/assets/).

pub const INDEX_HTML: &str = include_str!("../assets/index.html");
pub const APP_JS: &str = include_str!("../assets/app.js");
pub const STYLE_CSS: &str = include_str!("../assets/style.css");
