//! A msgpack writer producing what the reference encoder (Python msgpack, `use_bin_type`)
//! produces: the smallest int, str and container forms, floats as float 64, bytes as `bin`.

use rmp::encode;

pub(crate) struct Packer {
    buf: Vec<u8>,
}

// Writing into a Vec cannot fail: the io errors rmp reports are impossible here.
impl Packer {
    pub fn new(capacity: usize) -> Self {
        Self {
            buf: Vec::with_capacity(capacity),
        }
    }

    pub fn finish(self) -> Vec<u8> {
        self.buf
    }

    pub fn map(&mut self, len: usize) -> &mut Self {
        let _ = encode::write_map_len(&mut self.buf, len as u32);
        self
    }

    pub fn array(&mut self, len: usize) -> &mut Self {
        let _ = encode::write_array_len(&mut self.buf, len as u32);
        self
    }

    pub fn str(&mut self, s: &str) -> &mut Self {
        let _ = encode::write_str(&mut self.buf, s);
        self
    }

    pub fn uint(&mut self, v: u64) -> &mut Self {
        let _ = encode::write_uint(&mut self.buf, v);
        self
    }

    pub fn bool(&mut self, v: bool) -> &mut Self {
        let _ = encode::write_bool(&mut self.buf, v);
        self
    }

    pub fn nil(&mut self) -> &mut Self {
        let _ = encode::write_nil(&mut self.buf);
        self
    }

    pub fn f64(&mut self, v: f64) -> &mut Self {
        let _ = encode::write_f64(&mut self.buf, v);
        self
    }

    pub fn bin(&mut self, b: &[u8]) -> &mut Self {
        let _ = encode::write_bin(&mut self.buf, b);
        self
    }

    pub fn key(&mut self, k: &str) -> &mut Self {
        self.str(k)
    }

    pub fn opt_uint(&mut self, v: Option<u64>) -> &mut Self {
        match v {
            Some(v) => self.uint(v),
            None => self.nil(),
        }
    }

    pub fn opt_str(&mut self, v: Option<&str>) -> &mut Self {
        match v {
            Some(v) => self.str(v),
            None => self.nil(),
        }
    }

    pub fn strs(&mut self, items: &[String]) -> &mut Self {
        self.array(items.len());
        items.iter().for_each(|s| {
            self.str(s);
        });
        self
    }

    pub fn f64s(&mut self, items: &[f64]) -> &mut Self {
        self.array(items.len());
        items.iter().for_each(|&v| {
            self.f64(v);
        });
        self
    }
}
