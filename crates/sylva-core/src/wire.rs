//! Bytes in, bytes out: the little-endian encoding of what processes send each other (jobs'
//! results, data shared from the root, the work queue's messages). Hand-written rather than
//! serde + postcard because its payloads are long runs of `f32`, copied as they are
//! (docs/ARCHITECTURE.md, "Hand-written on purpose").

/// Data that does not read as what was written: running short, left over, or a length that
/// does not fit (a bug, or processes of different builds).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct WireError(pub String);

/// Appends values to a buffer.
#[derive(Debug, Default)]
pub struct Writer(pub Vec<u8>);

impl Writer {
    pub fn u64(&mut self, v: u64) -> &mut Self {
        self.0.extend_from_slice(&v.to_le_bytes());
        self
    }

    pub fn f64(&mut self, v: f64) -> &mut Self {
        self.0.extend_from_slice(&v.to_le_bytes());
        self
    }

    pub fn f32s(&mut self, v: &[f32]) -> &mut Self {
        self.0.reserve(4 * v.len());
        for x in v {
            self.0.extend_from_slice(&x.to_le_bytes());
        }
        self
    }

    /// A length, then the bytes.
    pub fn bytes(&mut self, v: &[u8]) -> &mut Self {
        self.u64(v.len() as u64);
        self.0.extend_from_slice(v);
        self
    }

    /// A length, then the values.
    pub fn u64s(&mut self, v: &[u64]) -> &mut Self {
        self.u64(v.len() as u64);
        for &x in v {
            self.u64(x);
        }
        self
    }
}

/// Reads what a [`Writer`] wrote; an error names `what`.
pub struct Reader<'a> {
    data: &'a [u8],
    what: &'static str,
}

impl<'a> Reader<'a> {
    pub fn new(data: &'a [u8], what: &'static str) -> Reader<'a> {
        Reader { data, what }
    }

    fn take(&mut self, n: usize) -> Result<&'a [u8], WireError> {
        if self.data.len() < n {
            return Err(WireError(format!(
                "{}: {} bytes short",
                self.what,
                n - self.data.len()
            )));
        }
        let (head, rest) = self.data.split_at(n);
        self.data = rest;
        Ok(head)
    }

    pub fn u64(&mut self) -> Result<u64, WireError> {
        Ok(u64::from_le_bytes(self.take(8)?.try_into().expect("8")))
    }

    pub fn f64(&mut self) -> Result<f64, WireError> {
        Ok(f64::from_le_bytes(self.take(8)?.try_into().expect("8")))
    }

    /// `n` f32 values.
    pub fn f32s(&mut self, n: usize) -> Result<Vec<f32>, WireError> {
        let b = self.take(
            n.checked_mul(4)
                .ok_or_else(|| WireError(format!("{}: {n} values", self.what)))?,
        )?;
        Ok(b.chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().expect("4")))
            .collect())
    }

    pub fn bytes(&mut self) -> Result<&'a [u8], WireError> {
        let n = self.u64()?;
        let n = usize::try_from(n).map_err(|_| WireError(format!("{}: {n} bytes", self.what)))?;
        self.take(n)
    }

    /// What [`Writer::u64s`] wrote, each below `bound` (an index into something of that
    /// length).
    pub fn indices(&mut self, bound: usize) -> Result<Vec<usize>, WireError> {
        let n = self.u64()?;
        if n > self.data.len() as u64 / 8 {
            return Err(WireError(format!("{}: {n} values", self.what)));
        }
        (0..n)
            .map(|_| {
                let v = self.u64()?;
                usize::try_from(v)
                    .ok()
                    .filter(|&i| i < bound)
                    .ok_or_else(|| WireError(format!("{}: index {v} of {bound}", self.what)))
            })
            .collect()
    }

    /// Fails unless everything was read.
    pub fn end(&self) -> Result<(), WireError> {
        if self.data.is_empty() {
            Ok(())
        } else {
            Err(WireError(format!(
                "{}: {} bytes too many",
                self.what,
                self.data.len()
            )))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_round_trip_and_short_or_long_data_is_refused() {
        let mut w = Writer::default();
        w.u64(7)
            .f64(-2.5)
            .f32s(&[1.0, f32::MIN_POSITIVE])
            .bytes(b"ab")
            .u64s(&[0, 2]);
        let mut r = Reader::new(&w.0, "test");
        assert_eq!(r.u64().unwrap(), 7);
        assert_eq!(r.f64().unwrap(), -2.5);
        assert_eq!(r.f32s(2).unwrap(), vec![1.0, f32::MIN_POSITIVE]);
        assert_eq!(r.bytes().unwrap(), b"ab");
        assert_eq!(r.indices(3).unwrap(), vec![0, 2]);
        r.end().unwrap();

        let mut short = Reader::new(&w.0[..5], "short");
        assert_eq!(short.u64().unwrap_err().0, "short: 3 bytes short");
        let long = Reader::new(&w.0, "long");
        assert!(long.end().unwrap_err().0.contains("too many"));
        let mut out_of_range = Writer::default();
        out_of_range.u64s(&[5]);
        let e = Reader::new(&out_of_range.0, "models")
            .indices(3)
            .unwrap_err();
        assert_eq!(e.0, "models: index 5 of 3");
        // A length beyond the data is refused before anything is allocated for it.
        let mut huge = Writer::default();
        huge.u64(u64::MAX);
        assert!(Reader::new(&huge.0, "huge").indices(3).is_err());
    }
}
