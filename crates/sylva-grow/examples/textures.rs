//! Writes each built-in species' leaf and bark textures side by side as raw RGB (leaf over
//! white), 128 pixels high: `cargo run --release -p sylva-grow --example textures -- OUT.rgb`.

use sylva_grow::Species;

fn main() {
    let out = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "textures.rgb".into());
    let species = Species::all_builtin();
    let (w, h) = (species.len() * 192, 128);
    let mut img = vec![255u8; w * h * 3];
    for (k, s) in species.iter().enumerate() {
        let mats = s.materials().expect("built-in species");
        let leaf = mats[1].texture.as_ref().unwrap();
        let bark = mats[0].texture.as_ref().unwrap();
        for y in 0..128u32 {
            for x in 0..128u32 {
                // Row 0 is v = 0 (the leaf base): draw it at the bottom.
                let t = leaf.texel(x, y);
                let a = t[3] as f32 / 255.0;
                let i = (((127 - y) as usize) * w + k * 192 + x as usize) * 3;
                for c in 0..3 {
                    img[i + c] = (t[c] as f32 * a + 255.0 * (1.0 - a)) as u8;
                }
            }
            for x in 0..64u32 {
                let t = bark.texel(x, y);
                let i = ((y as usize) * w + k * 192 + 128 + x as usize) * 3;
                img[i..i + 3].copy_from_slice(&t[..3]);
            }
        }
    }
    std::fs::write(&out, img).unwrap();
    println!("{w}x{h}");
}
