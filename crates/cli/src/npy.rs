//! NPY files (NumPy's `.npy` format, versions 1–3) holding a 2-D float array.
//!
//! Format: the magic `\x93NUMPY`, a major and minor version byte, the header
//! length (`u16` little-endian in version 1, `u32` in versions 2 and 3), a
//! header that is a Python dict literal
//! `{'descr': '<f8', 'fortran_order': False, 'shape': (rows, cols), }`,
//! then the raw values.
//!
//! Written here rather than taken from a crate because the header is
//! untrusted input: the general Python-literal parser of the `npyz` crate
//! backtracks exponentially on nested brackets (a 160-byte file found by
//! `fuzz/run.sh` kept it busy for minutes). This parser accepts exactly the
//! dict above, in one pass, and checks the claimed shape against the bytes
//! present before allocating anything.

/// A 2-D array, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct Array {
    /// Number of rows.
    pub rows: usize,
    /// Number of columns.
    pub cols: usize,
    /// `rows × cols` values, row-major (converted from Fortran order if needed).
    pub data: Vec<f64>,
}

/// Largest header accepted (NumPy writes well under 1 KiB).
const MAX_HEADER: usize = 1 << 16;

/// Parses an NPY file's bytes. Errors say what is wrong in one sentence.
pub fn parse(bytes: &[u8]) -> Result<Array, String> {
    let rest = bytes
        .strip_prefix(b"\x93NUMPY")
        .ok_or("no NPY magic number (\\x93NUMPY) at the start")?;
    let (&major, rest) = rest.split_first().ok_or("truncated before the version")?;
    let (_minor, rest) = rest.split_first().ok_or("truncated before the version")?;
    let (len, rest) = match major {
        1 => {
            let (l, r) = take(rest, 2).ok_or("truncated header length")?;
            (u16::from_le_bytes([l[0], l[1]]) as usize, r)
        }
        2 | 3 => {
            let (l, r) = take(rest, 4).ok_or("truncated header length")?;
            (u32::from_le_bytes([l[0], l[1], l[2], l[3]]) as usize, r)
        }
        v => return Err(format!("format version {v} is not supported (1, 2 or 3)")),
    };
    if len > MAX_HEADER {
        return Err(format!("header of {len} bytes is implausibly long"));
    }
    let (header, body) = take(rest, len).ok_or("truncated header")?;
    let header = std::str::from_utf8(header).map_err(|_| "header is not text")?;
    let h = Header::parse(header)?;
    if h.shape.len() != 2 {
        return Err(format!("shape {:?} is not 2-D", h.shape));
    }
    let (rows, cols) = (h.shape[0], h.shape[1]);
    let n = rows
        .checked_mul(cols)
        .and_then(|n| n.checked_mul(h.item))
        .ok_or_else(|| format!("shape {rows} × {cols} is too large"))?;
    if n > body.len() {
        return Err(format!(
            "header claims shape {rows} × {cols} ({n} bytes of data), but the file holds {} bytes after the header",
            body.len()
        ));
    }
    if n < body.len() {
        return Err(format!(
            "{} bytes follow the {rows} × {cols} array (corrupt or not one array)",
            body.len() - n
        ));
    }
    let value = |k: usize| -> f64 {
        let b = &body[k * h.item..(k + 1) * h.item];
        match (h.item, h.little) {
            (8, true) => f64::from_le_bytes(b.try_into().unwrap()),
            (8, false) => f64::from_be_bytes(b.try_into().unwrap()),
            (4, true) => f64::from(f32::from_le_bytes(b.try_into().unwrap())),
            _ => f64::from(f32::from_be_bytes(b.try_into().unwrap())),
        }
    };
    let mut data = Vec::with_capacity(rows * cols);
    for r in 0..rows {
        for c in 0..cols {
            data.push(value(if h.fortran {
                c * rows + r
            } else {
                r * cols + c
            }));
        }
    }
    Ok(Array { rows, cols, data })
}

/// The bytes of an NPY file (version 1.0, little-endian `f8`, C order)
/// holding `data` as a `rows × cols` array: what `numpy.load` reads.
pub fn write(rows: usize, cols: usize, data: &[f64]) -> Vec<u8> {
    assert_eq!(data.len(), rows * cols, "NPY data is rows × cols values");
    let dict = format!("{{'descr': '<f8', 'fortran_order': False, 'shape': ({rows}, {cols}), }}");
    // Magic (6) + version (2) + length (2) + dict + padding + newline: a multiple of 64.
    let unpadded = 10 + dict.len() + 1;
    let header_len = dict.len() + 1 + (64 - unpadded % 64) % 64;
    let mut out = Vec::with_capacity(10 + header_len + data.len() * 8);
    out.extend_from_slice(b"\x93NUMPY\x01\x00");
    out.extend_from_slice(&(header_len as u16).to_le_bytes());
    out.extend_from_slice(dict.as_bytes());
    out.resize(10 + header_len - 1, b' ');
    out.push(b'\n');
    for v in data {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out
}

fn take(b: &[u8], n: usize) -> Option<(&[u8], &[u8])> {
    (b.len() >= n).then(|| b.split_at(n))
}

/// The fields of the header dict this reader needs.
struct Header {
    /// Bytes per value (4 or 8).
    item: usize,
    little: bool,
    fortran: bool,
    shape: Vec<usize>,
}

/// A token stream over the header text; no recursion, no backtracking.
struct Lexer<'a> {
    s: &'a [u8],
    i: usize,
}

impl<'a> Lexer<'a> {
    fn skip_ws(&mut self) {
        while self.i < self.s.len() && self.s[self.i].is_ascii_whitespace() {
            self.i += 1;
        }
    }

    fn peek(&mut self) -> Option<u8> {
        self.skip_ws();
        self.s.get(self.i).copied()
    }

    fn expect(&mut self, c: u8) -> Result<(), String> {
        match self.peek() {
            Some(x) if x == c => {
                self.i += 1;
                Ok(())
            }
            other => Err(format!(
                "header: expected `{}`, found {}",
                c as char,
                other.map_or("the end".into(), |x| format!("`{}`", x as char))
            )),
        }
    }

    fn string(&mut self) -> Result<&'a str, String> {
        let q = self.peek().ok_or("header: unexpected end")?;
        if q != b'\'' && q != b'"' {
            return Err("header: expected a quoted string".into());
        }
        let start = self.i + 1;
        let end = self.s[start..]
            .iter()
            .position(|&c| c == q)
            .ok_or("header: unterminated string")?;
        self.i = start + end + 1;
        std::str::from_utf8(&self.s[start..start + end]).map_err(|_| "header: not text".into())
    }

    fn word(&mut self) -> &'a str {
        self.skip_ws();
        let start = self.i;
        while self.i < self.s.len() && self.s[self.i].is_ascii_alphanumeric() {
            self.i += 1;
        }
        std::str::from_utf8(&self.s[start..self.i]).unwrap_or("")
    }

    fn tuple(&mut self) -> Result<Vec<usize>, String> {
        self.expect(b'(')?;
        let mut out = Vec::new();
        loop {
            if self.peek() == Some(b')') {
                self.i += 1;
                return Ok(out);
            }
            let w = self.word();
            let n: usize = w
                .parse()
                .map_err(|_| format!("header: shape entry `{w}` is not a whole number"))?;
            out.push(n);
            if out.len() > 32 {
                return Err("header: shape has too many dimensions".into());
            }
            match self.peek() {
                Some(b',') => self.i += 1,
                Some(b')') => {}
                _ => return Err("header: malformed shape tuple".into()),
            }
        }
    }
}

impl Header {
    fn parse(text: &str) -> Result<Header, String> {
        let mut lx = Lexer {
            s: text.as_bytes(),
            i: 0,
        };
        let (mut descr, mut fortran, mut shape) = (None, None, None);
        lx.expect(b'{')?;
        loop {
            if lx.peek() == Some(b'}') {
                lx.i += 1;
                break;
            }
            let key = lx.string()?;
            lx.expect(b':')?;
            match key {
                "descr" => descr = Some(lx.string()?),
                "fortran_order" => {
                    fortran = Some(match lx.word() {
                        "True" => true,
                        "False" => false,
                        w => {
                            return Err(format!("header: fortran_order `{w}` is not True or False"))
                        }
                    })
                }
                "shape" => shape = Some(lx.tuple()?),
                other => return Err(format!("header: unknown key `{other}`")),
            }
            match lx.peek() {
                Some(b',') => lx.i += 1,
                Some(b'}') => {}
                _ => return Err("header: expected `,` or `}`".into()),
            }
        }
        if lx.peek().is_some() {
            return Err("header: text after the dict".into());
        }
        let descr = descr.ok_or("header has no `descr`")?;
        let (little, item) = match descr {
            "<f8" => (true, 8),
            "<f4" => (true, 4),
            ">f8" => (false, 8),
            ">f4" => (false, 4),
            "=f8" => (cfg!(target_endian = "little"), 8),
            "=f4" => (cfg!(target_endian = "little"), 4),
            other => return Err(format!("dtype {other} is not a float (f4 or f8)")),
        };
        Ok(Header {
            item,
            little,
            fortran: fortran.ok_or("header has no `fortran_order`")?,
            shape: shape.ok_or("header has no `shape`")?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn file(header: &str, body: &[u8]) -> Vec<u8> {
        let mut h = header.to_string();
        while !(10 + h.len() + 1).is_multiple_of(64) {
            h.push(' ');
        }
        h.push('\n');
        let mut v = b"\x93NUMPY\x01\x00".to_vec();
        v.extend((h.len() as u16).to_le_bytes());
        v.extend(h.as_bytes());
        v.extend(body);
        v
    }

    fn f8(values: &[f64]) -> Vec<u8> {
        values.iter().flat_map(|v| v.to_le_bytes()).collect()
    }

    #[test]
    fn reads_c_and_fortran_order_f8_and_f4() {
        let c = file(
            "{'descr': '<f8', 'fortran_order': False, 'shape': (2, 3), }",
            &f8(&[1., 2., 3., 4., 5., 6.]),
        );
        let a = parse(&c).unwrap();
        assert_eq!(
            (a.rows, a.cols, a.data),
            (2, 3, vec![1., 2., 3., 4., 5., 6.])
        );
        let f = file(
            "{'descr': '<f8', 'fortran_order': True, 'shape': (2, 3), }",
            &f8(&[1., 4., 2., 5., 3., 6.]),
        );
        assert_eq!(parse(&f).unwrap().data, vec![1., 2., 3., 4., 5., 6.]);
        let body: Vec<u8> = [1.5f32, -2.0]
            .iter()
            .flat_map(|v| v.to_be_bytes())
            .collect();
        let b = file(
            "{\"descr\": \">f4\", \"fortran_order\": False, \"shape\": (1, 2)}",
            &body,
        );
        assert_eq!(parse(&b).unwrap().data, vec![1.5, -2.0]);
    }

    #[test]
    fn refuses_what_it_cannot_read_in_one_pass() {
        let good = "{'descr': '<f8', 'fortran_order': False, 'shape': (2, 2), }";
        let cases: Vec<(Vec<u8>, &str)> = vec![
            (b"not npy".to_vec(), "magic"),
            (file(good, &f8(&[1., 2., 3.])), "claims shape 2 × 2"),
            (file(good, &f8(&[1., 2., 3., 4., 5.])), "bytes follow"),
            (
                file(
                    "{'descr': '<i8', 'fortran_order': False, 'shape': (1, 1), }",
                    &f8(&[1.]),
                ),
                "not a float",
            ),
            (
                file(
                    "{'descr': '<f8', 'fortran_order': False, 'shape': (4,), }",
                    &f8(&[1.; 4]),
                ),
                "not 2-D",
            ),
            (
                file(
                    "{'descr': '<f8', 'fortran_order': False, 'shape': (4294967296, 4294967296), }",
                    &[],
                ),
                "too large",
            ),
            (
                file(&("{".repeat(100) + "'descr': '<f8'}"), &[]),
                "expected a quoted string",
            ),
            (
                file(
                    "{'descr': '<f8', 'fortran_order': Maybe, 'shape': (1, 1), }",
                    &f8(&[1.]),
                ),
                "True or False",
            ),
        ];
        for (bytes, want) in cases {
            let err = parse(&bytes).unwrap_err();
            assert!(err.contains(want), "{err:?} should mention {want:?}");
        }
    }
}
