//! Per-streamline weights as text: MRtrix3's `tcksift2` output and `tckedit -tck_weights_in/-tck_weights_out`.
//!
//! A file holds one number per streamline, in the tractogram's order, separated by whitespace or commas, on one
//! line or many; a `#` starts a comment that runs to the end of its line. [`WeightReader`] streams the numbers
//! (a whole-brain file is one line of 10M numbers, never held as one string) and [`WeightWriter`] writes them on
//! one line, as `tckedit` does, whole or not at all.

use std::fs::File;
use std::io::{BufRead, BufReader, BufWriter, Write};
use std::path::{Path, PathBuf};

use crate::error::{Error, Result};

/// Reads weights in order, `n` at a time, beside a tractogram read in chunks.
pub struct WeightReader {
    path: PathBuf,
    input: Box<dyn BufRead + Send>,
    /// Weights read so far.
    count: u64,
    line: u64,
    in_comment: bool,
    token: Vec<u8>,
}

impl WeightReader {
    /// Opens a weights file.
    pub fn open(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref().to_path_buf();
        let file = File::open(&path).map_err(|e| Error::io(&path, e))?;
        Ok(Self::from_reader(path, BufReader::with_capacity(1 << 16, file)))
    }

    fn from_reader(path: PathBuf, input: impl BufRead + Send + 'static) -> Self {
        Self { path, input: Box::new(input), count: 0, line: 1, in_comment: false, token: Vec::new() }
    }

    /// The weights read so far.
    pub fn count(&self) -> u64 {
        self.count
    }

    /// The next weight, or None at the end of the file.
    pub fn next_weight(&mut self) -> Result<Option<f32>> {
        self.token.clear();
        let mut token_line = self.line;
        loop {
            let buf = self.input.fill_buf().map_err(|e| Error::io(&self.path, e))?;
            if buf.is_empty() {
                break;
            }
            let mut used = 0;
            let mut done = false;
            for &b in buf {
                used += 1;
                if b == b'\n' {
                    self.line += 1;
                    self.in_comment = false;
                    if !self.token.is_empty() {
                        done = true;
                        break;
                    }
                    continue;
                }
                if self.in_comment {
                    continue;
                }
                if b == b'#' {
                    self.in_comment = true;
                    if !self.token.is_empty() {
                        done = true;
                        break;
                    }
                } else if b.is_ascii_whitespace() || b == b',' {
                    if !self.token.is_empty() {
                        done = true;
                        break;
                    }
                } else {
                    if self.token.is_empty() {
                        token_line = self.line;
                    }
                    if self.token.len() > 64 {
                        return Err(Error::format(
                            &self.path,
                            format!("line {token_line}: a value longer than 64 characters is not a weight"),
                        ));
                    }
                    self.token.push(b);
                }
            }
            self.input.consume(used);
            if done {
                break;
            }
        }
        if self.token.is_empty() {
            return Ok(None);
        }
        let text = String::from_utf8_lossy(&self.token);
        let w: f32 = text.parse().map_err(|_| {
            Error::format(
                &self.path,
                format!("line {token_line}: '{text}' (weight {}) is not a number", self.count + 1),
            )
        })?;
        if !w.is_finite() {
            return Err(Error::format(&self.path, format!("line {token_line}: weight {} is {w}", self.count + 1)));
        }
        self.count += 1;
        Ok(Some(w))
    }

    /// The next `n` weights; an error naming the file when it holds fewer.
    pub fn take(&mut self, n: usize) -> Result<Vec<f32>> {
        let mut out = Vec::with_capacity(n);
        while out.len() < n {
            match self.next_weight()? {
                Some(w) => out.push(w),
                None => {
                    return Err(Error::format(
                        &self.path,
                        format!(
                            "{} weights, fewer than the tractogram's streamlines (at least {})",
                            self.count,
                            self.count + (n - out.len()) as u64
                        ),
                    ));
                }
            }
        }
        Ok(out)
    }

    /// Ends the reading after `streamlines` streamlines: an error when the file holds more weights.
    pub fn finish(mut self, streamlines: u64) -> Result<()> {
        if self.next_weight()?.is_some() {
            let mut extra = 1u64;
            while self.next_weight()?.is_some() {
                extra += 1;
            }
            return Err(Error::format(
                &self.path,
                format!("{} weights, more than the tractogram's {streamlines} streamlines", streamlines + extra),
            ));
        }
        Ok(())
    }
}

/// Reads every weight of a file.
pub fn read(path: impl AsRef<Path>) -> Result<Vec<f32>> {
    let mut r = WeightReader::open(path)?;
    let mut out = Vec::new();
    while let Some(w) = r.next_weight()? {
        out.push(w);
    }
    Ok(out)
}

/// Writes weights on one line (`OUT.part`, moved into place by [`WeightWriter::finish`]).
pub struct WeightWriter {
    path: PathBuf,
    part: PathBuf,
    out: BufWriter<File>,
    count: u64,
    /// Removes the part file when the writer is dropped unfinished.
    _leftovers: super::stream::Leftovers,
}

impl WeightWriter {
    /// Creates `path.part`.
    pub fn create(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref().to_path_buf();
        let part = super::stream::part_path(&path);
        let file = File::create(&part).map_err(|e| Error::io(&part, e))?;
        let _leftovers = super::stream::Leftovers(vec![part.clone()]);
        Ok(Self { path, part, out: BufWriter::with_capacity(1 << 16, file), count: 0, _leftovers })
    }

    /// Appends weights.
    pub fn write(&mut self, weights: &[f32]) -> Result<()> {
        for w in weights {
            let sep = if self.count == 0 { "" } else { " " };
            write!(self.out, "{sep}{w}").map_err(|e| Error::io(&self.part, e))?;
            self.count += 1;
        }
        Ok(())
    }

    /// Ends the line and moves the file into place; the number of weights written.
    pub fn finish(mut self) -> Result<u64> {
        writeln!(self.out).and_then(|_| self.out.flush()).map_err(|e| Error::io(&self.part, e))?;
        drop(self.out);
        std::fs::rename(&self.part, &self.path).map_err(|e| Error::io(&self.path, e))?;
        Ok(self.count)
    }
}

/// Writes every weight to `path`.
pub fn write(path: impl AsRef<Path>, weights: &[f32]) -> Result<()> {
    let mut w = WeightWriter::create(path)?;
    w.write(weights)?;
    w.finish().map(|_| ())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reader(text: &str) -> WeightReader {
        WeightReader::from_reader(PathBuf::from("w.txt"), std::io::Cursor::new(text.as_bytes().to_vec()))
    }

    #[test]
    fn reads_rows_columns_commas_and_comments() {
        let mut r = reader("# tcksift2 output\n0.5 1.25,2e-1\n  3 # trailing\n\n4\t5");
        assert_eq!(r.take(3).unwrap(), vec![0.5, 1.25, 0.2]);
        assert_eq!(r.take(3).unwrap(), vec![3.0, 4.0, 5.0]);
        r.finish(6).unwrap();
    }

    #[test]
    fn counts_must_match_and_values_be_numbers() {
        let e = reader("1 2").take(3).unwrap_err().to_string();
        assert!(e.contains("w.txt") && e.contains("2 weights, fewer"), "{e}");
        let mut r = reader("1 2 3 4");
        r.take(2).unwrap();
        let e = r.finish(2).unwrap_err().to_string();
        assert!(e.contains("4 weights, more than the tractogram's 2"), "{e}");
        let e = reader("1\n2 x3").take(3).unwrap_err().to_string();
        assert!(e.contains("line 2") && e.contains("'x3'") && e.contains("weight 3"), "{e}");
        let e = reader("1 nan").take(2).unwrap_err().to_string();
        assert!(e.contains("weight 2 is NaN"), "{e}");
        let e = reader(&"9".repeat(100)).take(1).unwrap_err().to_string();
        assert!(e.contains("longer than 64"), "{e}");
    }

    #[test]
    fn writes_one_line_that_reads_back() {
        let tmp_dir = tempfile::Builder::new().prefix("fascicle_weights-").tempdir().unwrap();
        let dir = tmp_dir.path().to_path_buf();
        let p = dir.join("w.txt");
        let ws = [0.8474f32, 1e-7, 3.0, 123_456.8];
        let mut w = WeightWriter::create(&p).unwrap();
        w.write(&ws[..2]).unwrap();
        w.write(&ws[2..]).unwrap();
        assert!(!p.exists(), "written whole or not at all");
        assert_eq!(w.finish().unwrap(), 4);
        let mut unfinished = WeightWriter::create(dir.join("u.txt")).unwrap();
        unfinished.write(&ws).unwrap();
        drop(unfinished);
        assert!(!dir.join("u.txt").exists() && !dir.join("u.txt.part").exists(), "an unfinished file is removed");
        let text = std::fs::read_to_string(&p).unwrap();
        assert_eq!(text.lines().count(), 1);
        assert_eq!(read(&p).unwrap(), ws);
    }
}
