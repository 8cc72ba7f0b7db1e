//! An 8-bit RGB image and its PNG encoding.

use crate::error::RenderError;
use std::path::Path;

/// An RGB image, 8 bits per channel, rows top to bottom.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Image {
    pub width: u32,
    pub height: u32,
    /// `3 * width * height` bytes: `r g b` of pixel `(x, y)` at
    /// `3 * (y * width + x)`.
    pub rgb: Vec<u8>,
}

impl Image {
    /// An image filled with `color`.
    pub fn new(width: u32, height: u32, color: [u8; 3]) -> Self {
        let n = width as usize * height as usize;
        let mut rgb = Vec::with_capacity(3 * n);
        for _ in 0..n {
            rgb.extend_from_slice(&color);
        }
        Self { width, height, rgb }
    }

    /// The colour of pixel `(x, y)`.
    ///
    /// # Panics
    /// If the pixel is outside the image.
    pub fn pixel(&self, x: u32, y: u32) -> [u8; 3] {
        assert!(
            x < self.width && y < self.height,
            "pixel ({x}, {y}) outside"
        );
        let i = 3 * (y as usize * self.width as usize + x as usize);
        [self.rgb[i], self.rgb[i + 1], self.rgb[i + 2]]
    }

    /// Sets pixel `(x, y)`; pixels outside the image are ignored, so drawing
    /// code may run over the border.
    pub fn set_pixel(&mut self, x: i64, y: i64, color: [u8; 3]) {
        if x >= 0 && y >= 0 && (x as u64) < self.width as u64 && (y as u64) < self.height as u64 {
            let i = 3 * (y as usize * self.width as usize + x as usize);
            self.rgb[i..i + 3].copy_from_slice(&color);
        }
    }

    /// Mixes `color` into pixel `(x, y)` with weight `alpha` in `[0, 1]`
    /// (ignored outside the image).
    pub fn blend_pixel(&mut self, x: i64, y: i64, color: [u8; 3], alpha: f32) {
        if x >= 0 && y >= 0 && (x as u64) < self.width as u64 && (y as u64) < self.height as u64 {
            let i = 3 * (y as usize * self.width as usize + x as usize);
            let old = [self.rgb[i], self.rgb[i + 1], self.rgb[i + 2]];
            self.rgb[i..i + 3].copy_from_slice(&blend(old, color, alpha));
        }
    }

    /// Fills the rectangle `[x0, x1) × [y0, y1)` (clipped to the image).
    pub fn fill_rect(&mut self, x0: i64, y0: i64, x1: i64, y1: i64, color: [u8; 3]) {
        let (w, h) = (self.width as i64, self.height as i64);
        for y in y0.max(0)..y1.min(h) {
            for x in x0.max(0)..x1.min(w) {
                let i = 3 * (y as usize * self.width as usize + x as usize);
                self.rgb[i..i + 3].copy_from_slice(&color);
            }
        }
    }

    /// How many pixels differ from `color`.
    pub fn count_not(&self, color: [u8; 3]) -> usize {
        self.rgb.chunks_exact(3).filter(|p| *p != color).count()
    }

    /// PNG bytes (fast deflate: previews are written often and read rarely).
    pub fn encode_png(&self) -> Result<Vec<u8>, png::EncodingError> {
        let mut out = Vec::with_capacity(self.rgb.len() / 4);
        {
            let mut enc = png::Encoder::new(&mut out, self.width, self.height);
            enc.set_color(png::ColorType::Rgb);
            enc.set_depth(png::BitDepth::Eight);
            enc.set_compression(png::Compression::Fast);
            let mut w = enc.write_header()?;
            w.write_image_data(&self.rgb)?;
            w.finish()?;
        }
        Ok(out)
    }

    /// Writes the image as PNG, replacing `path` in one rename.
    pub fn write_png(&self, path: &Path) -> Result<(), RenderError> {
        let bytes = self.encode_png().map_err(|e| RenderError::Encode {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        crate::files::write_replacing(path, &bytes)
    }

    /// Reads an 8-bit RGB or RGBA PNG (alpha dropped), e.g. a frame written by
    /// [`Image::write_png`].
    pub fn read_png(path: &Path) -> Result<Image, RenderError> {
        let bytes = std::fs::read(path).map_err(|e| RenderError::io(path, e))?;
        let bad = |message: String| RenderError::format(path, None, message);
        let mut reader = png::Decoder::new(std::io::Cursor::new(bytes))
            .read_info()
            .map_err(|e| bad(e.to_string()))?;
        let size = reader
            .output_buffer_size()
            .ok_or_else(|| bad("image too large".into()))?;
        let mut buf = vec![0; size];
        let info = reader
            .next_frame(&mut buf)
            .map_err(|e| bad(e.to_string()))?;
        if info.bit_depth != png::BitDepth::Eight {
            return Err(bad(format!(
                "{:?} bits per channel; expected 8",
                info.bit_depth
            )));
        }
        let (w, h) = (info.width, info.height);
        let rgb = match info.color_type {
            png::ColorType::Rgb => buf[..3 * (w * h) as usize].to_vec(),
            png::ColorType::Rgba => buf[..4 * (w * h) as usize]
                .chunks_exact(4)
                .flat_map(|p| [p[0], p[1], p[2]])
                .collect(),
            other => return Err(bad(format!("colour type {other:?}; expected RGB"))),
        };
        Ok(Image {
            width: w,
            height: h,
            rgb,
        })
    }
}

/// `old` mixed with `color` with weight `alpha` in `[0, 1]`, rounded: what
/// [`Image::blend_pixel`] writes.
pub fn blend(old: [u8; 3], color: [u8; 3], alpha: f32) -> [u8; 3] {
    let a = alpha.clamp(0.0, 1.0);
    std::array::from_fn(|c| {
        let old = old[c] as f32;
        (old + (color[c] as f32 - old) * a + 0.5) as u8
    })
}
