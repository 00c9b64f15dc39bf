//! A straight-alpha RGBA8 image in memory, row by row: what the overlay draws (the legend, a
//! status line). Its own small type, so that the pass and the renderer need no image crate
//! (PNG files are the `png` feature's).

/// `width × height` RGBA8 pixels, row-major, top row first.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RgbaPixels {
    width: u32,
    height: u32,
    data: Vec<u8>,
}

impl RgbaPixels {
    /// Every pixel `p`.
    pub fn from_pixel(width: u32, height: u32, p: [u8; 4]) -> RgbaPixels {
        let data = p.repeat(width as usize * height as usize);
        RgbaPixels {
            width,
            height,
            data,
        }
    }

    /// Pixel `(x, y)` from `f(x, y)`.
    pub fn from_fn(width: u32, height: u32, mut f: impl FnMut(u32, u32) -> [u8; 4]) -> RgbaPixels {
        let mut data = Vec::with_capacity(4 * width as usize * height as usize);
        for y in 0..height {
            for x in 0..width {
                data.extend_from_slice(&f(x, y));
            }
        }
        RgbaPixels {
            width,
            height,
            data,
        }
    }

    /// Width in pixels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// `(width, height)`.
    pub fn dimensions(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    fn at(&self, x: u32, y: u32) -> usize {
        assert!(
            x < self.width && y < self.height,
            "pixel ({x}, {y}) outside {}×{}",
            self.width,
            self.height
        );
        4 * (y as usize * self.width as usize + x as usize)
    }

    /// Pixel `(x, y)`; panics outside the image.
    pub fn get_pixel(&self, x: u32, y: u32) -> [u8; 4] {
        let i = self.at(x, y);
        [
            self.data[i],
            self.data[i + 1],
            self.data[i + 2],
            self.data[i + 3],
        ]
    }

    /// Pixel `(x, y)`, to change; panics outside the image.
    pub fn get_pixel_mut(&mut self, x: u32, y: u32) -> &mut [u8] {
        let i = self.at(x, y);
        &mut self.data[i..i + 4]
    }

    /// Sets pixel `(x, y)`; panics outside the image.
    pub fn put_pixel(&mut self, x: u32, y: u32, p: [u8; 4]) {
        self.get_pixel_mut(x, y).copy_from_slice(&p);
    }

    /// Every pixel, row by row.
    pub fn pixels(&self) -> impl Iterator<Item = [u8; 4]> + '_ {
        (self.data.chunks_exact(4)).map(|p| [p[0], p[1], p[2], p[3]])
    }

    /// The bytes, row by row (`4·width·height`).
    pub fn as_raw(&self) -> &[u8] {
        &self.data
    }
}
