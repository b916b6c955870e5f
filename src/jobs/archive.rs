//! A scan as it arrives: one file, several (a glTF with its `.bin` and textures, an OBJ with
//! its MTL and images, picked together or as their folder), or one `.zip` holding them. Every
//! upload route hands its received files to [`assemble`], which unpacks a `.zip` (entries under
//! plain relative paths only, bounded in count, size and compression ratio) and picks the one
//! scan among the files; the others travel with it as its companions.

use std::io::{Read, Write};
use std::path::Path;

use super::{Companion, JobError, MAX_SCAN_FILES, ReceivedScan, SCAN_EXTENSIONS};
use crate::uploads::TempUpload;

/// A received file: its relative path (checked with [`super::companion_path`]) and bytes.
#[derive(Debug)]
pub struct ReceivedFile {
    /// Relative path.
    pub relative: String,
    /// The bytes, in a guarded temporary file of `uploads/`.
    pub temp: TempUpload,
    /// Their length.
    pub bytes: u64,
}

/// How much larger than the archive its unpacked files may be together: real scans compress
/// a few times (ASCII formats up to about 10×); a "zip bomb" expands up to 1,000×.
pub const MAX_ZIP_RATIO: u64 = 100;
/// What a small archive may always unpack to, whatever its ratio.
pub const ZIP_RATIO_FLOOR: u64 = 64 << 20;

/// Whether a file name is that of a zip archive.
pub fn is_zip(name: &str) -> bool {
    name.rsplit(['/', '\\'])
        .next()
        .and_then(|n| n.rsplit_once('.'))
        .is_some_and(|(_, ext)| ext.eq_ignore_ascii_case("zip"))
}

/// The scan among `files` (a single `.zip` is unpacked first, into `uploads`, at most `limit`
/// bytes); blocking (unpacking reads and writes files).
pub fn assemble(
    mut files: Vec<ReceivedFile>,
    uploads: &Path,
    limit: u64,
) -> Result<ReceivedScan, JobError> {
    if files.len() == 1 && is_zip(&files[0].relative) {
        let zip = files.remove(0);
        files = unpack_zip(&zip, uploads, limit)?;
    } else if files.iter().any(|f| is_zip(&f.relative)) {
        return Err(JobError::Invalid(
            "upload a .zip on its own (it holds the scan and the files it refers to)".into(),
        ));
    }
    let scans: Vec<usize> = (0..files.len())
        .filter(|&i| super::scan_extension(&files[i].relative).is_some())
        .collect();
    let main = match scans.as_slice() {
        [i] => *i,
        [] if files.is_empty() => {
            return Err(JobError::Invalid("choose a scan file to upload".into()));
        }
        [] => {
            return Err(JobError::Invalid(format!(
                "none of the files is a scan: one must end in {SCAN_EXTENSIONS}"
            )));
        }
        many => {
            let names: Vec<&str> = many
                .iter()
                .take(4)
                .map(|&i| files[i].relative.as_str())
                .collect();
            return Err(JobError::Invalid(format!(
                "upload one scan at a time (with the files it refers to), not {}",
                names.join(", ")
            )));
        }
    };
    let scan = files.remove(main);
    if scan.bytes == 0 {
        return Err(JobError::Invalid("the scan is empty".into()));
    }
    let extension = super::scan_extension(&scan.relative)
        .ok_or_else(|| JobError::Invalid("the scan has no known extension".into()))?;
    Ok(ReceivedScan {
        temp: scan.temp,
        bytes: scan.bytes,
        extension,
        display_name: display_name(&scan.relative),
        relative: scan.relative,
        companions: files
            .into_iter()
            .map(|f| Companion {
                relative: f.relative,
                temp: f.temp,
                bytes: f.bytes,
            })
            .collect(),
    })
}

/// A file as shown to people: the last component of its path, printable characters only
/// (no quotes or angle brackets), at most 200 of them.
fn display_name(relative: &str) -> String {
    let last = relative.rsplit(['/', '\\']).next().unwrap_or("");
    let clean: String = last
        .chars()
        .filter(|c| !c.is_control() && !matches!(c, '"' | '<' | '>'))
        .take(200)
        .collect();
    let clean = clean.trim().trim_start_matches('.');
    if clean.is_empty() {
        "scan".into()
    } else {
        clean.to_string()
    }
}

/// Entries of archives that are no part of a scan (made by the archiver).
fn archiver_litter(name: &str) -> bool {
    name.starts_with("__MACOSX/")
        || name
            .rsplit('/')
            .next()
            .is_some_and(|n| n == ".DS_Store" || n == "Thumbs.db")
}

fn zip_error(e: zip::result::ZipError) -> JobError {
    JobError::Invalid(format!("the .zip cannot be read: {e}"))
}

/// Unpacks the files of a zip archive into temporary files of `uploads`, each under a plain
/// relative path; refuses more than [`MAX_SCAN_FILES`] files, more than `limit` bytes, or more
/// than [`MAX_ZIP_RATIO`] times the archive's size (counted as they are written, not as the
/// archive declares), and encrypted entries or unknown compression methods.
fn unpack_zip(
    zip: &ReceivedFile,
    uploads: &Path,
    limit: u64,
) -> Result<Vec<ReceivedFile>, JobError> {
    let file = std::fs::File::open(zip.temp.path())?;
    let mut archive = zip::ZipArchive::new(std::io::BufReader::new(file)).map_err(zip_error)?;
    let budget = limit.min(zip.bytes.saturating_mul(MAX_ZIP_RATIO).max(ZIP_RATIO_FLOOR));
    let mut total = 0u64;
    let mut out: Vec<ReceivedFile> = Vec::new();
    for i in 0..archive.len() {
        let mut entry = archive.by_index(i).map_err(zip_error)?;
        let raw = entry.name().map_err(zip_error)?.into_owned();
        if entry.is_dir() || archiver_litter(&raw) {
            continue;
        }
        let relative = super::companion_path(&raw).ok_or_else(|| {
            JobError::Invalid(format!(
                "the .zip holds {:?}, which is not a plain relative path",
                display_name(&raw)
            ))
        })?;
        if out.len() == MAX_SCAN_FILES {
            return Err(JobError::Invalid(format!(
                "the .zip holds more than {MAX_SCAN_FILES} files: only the scan and the files it refers to belong in it"
            )));
        }
        if out.iter().any(|f| f.relative == relative) {
            return Err(JobError::Invalid(format!(
                "the .zip holds {relative} twice"
            )));
        }
        let temp = TempUpload::new(uploads);
        let mut dest =
            std::io::BufWriter::with_capacity(1 << 20, std::fs::File::create(temp.path())?);
        let mut buf = vec![0u8; 1 << 16];
        let mut bytes = 0u64;
        loop {
            let n = match entry.read(&mut buf) {
                Ok(0) => break,
                Ok(n) => n,
                Err(e) => {
                    return Err(JobError::Invalid(format!(
                        "the .zip cannot be read at {relative}: {e}"
                    )));
                }
            };
            bytes += n as u64;
            total += n as u64;
            if total > budget {
                return Err(JobError::TooLarge(if budget == limit {
                    format!("the .zip unpacks to more than the upload limit of {limit} bytes")
                } else {
                    format!(
                        "the .zip unpacks to more than {MAX_ZIP_RATIO} times its size: it is not a scan archive"
                    )
                }));
            }
            dest.write_all(&buf[..n])?;
        }
        dest.flush()?;
        dest.get_ref().sync_data()?;
        out.push(ReceivedFile {
            relative,
            temp,
            bytes,
        });
    }
    if out.is_empty() {
        return Err(JobError::Invalid("the .zip holds no file".into()));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn received(dir: &Path, name: &str, bytes: &[u8]) -> ReceivedFile {
        let temp = TempUpload::new(dir);
        std::fs::write(temp.path(), bytes).expect("write");
        ReceivedFile {
            relative: name.into(),
            temp,
            bytes: bytes.len() as u64,
        }
    }

    fn zip_of(entries: &[(&str, &[u8])], method: zip::CompressionMethod) -> Vec<u8> {
        let mut w = zip::ZipWriter::new(std::io::Cursor::new(Vec::new()));
        let opts = zip::write::SimpleFileOptions::default().compression_method(method);
        for (name, data) in entries {
            w.start_file(*name, opts).expect("start");
            w.write_all(data).expect("write");
        }
        w.finish().expect("finish").into_inner()
    }

    #[test]
    fn files_and_archives_become_one_scan() {
        let dir = tempfile::tempdir().expect("tempdir");
        let d = dir.path();
        let scan = assemble(
            vec![
                received(d, "m/a.mtl", b"newmtl x"),
                received(d, "m/a.obj", b"v 0 0 0"),
            ],
            d,
            1 << 20,
        )
        .expect("assemble");
        assert_eq!(
            (scan.relative.as_str(), scan.extension.as_str()),
            ("m/a.obj", "obj")
        );
        assert_eq!(scan.companions.len(), 1);

        let z = zip_of(
            &[
                ("mask/scene.gltf", b"{}"),
                ("mask/scene.bin", &[7u8; 5000]),
                ("__MACOSX/mask/._scene.gltf", b"junk"),
            ],
            zip::CompressionMethod::Deflated,
        );
        let scan = assemble(vec![received(d, "mask.ZIP", &z)], d, 1 << 20).expect("unzip");
        assert_eq!(scan.relative, "mask/scene.gltf");
        assert_eq!(scan.companions.len(), 1);
        assert_eq!(scan.companions[0].bytes, 5000);
        assert_eq!(
            std::fs::read(scan.companions[0].temp.path()).expect("read"),
            vec![7u8; 5000]
        );
    }

    #[test]
    fn bad_archives_are_refused_with_their_cause() {
        let dir = tempfile::tempdir().expect("tempdir");
        let d = dir.path();
        let refuse = |files: Vec<ReceivedFile>, limit: u64, want: &str| {
            let e = assemble(files, d, limit).expect_err(want);
            assert!(e.to_string().contains(want), "{e} lacks {want:?}");
        };
        let stored = zip::CompressionMethod::Stored;
        refuse(
            vec![received(d, "x.zip", b"not a zip")],
            1 << 20,
            "cannot be read",
        );
        refuse(
            vec![received(
                d,
                "x.zip",
                &zip_of(&[("../evil.ply", b"ply")], stored),
            )],
            1 << 20,
            "not a plain relative path",
        );
        refuse(
            vec![received(
                d,
                "x.zip",
                &zip_of(&[("/etc/evil.ply", b"ply")], stored),
            )],
            1 << 20,
            "not a plain relative path",
        );
        refuse(
            vec![received(
                d,
                "x.zip",
                &zip_of(&[("a.ply", b"ply"), ("b.obj", b"v")], stored),
            )],
            1 << 20,
            "one scan at a time",
        );
        refuse(
            vec![received(
                d,
                "x.zip",
                &zip_of(&[("notes.txt", b"hi")], stored),
            )],
            1 << 20,
            "none of the files is a scan",
        );
        refuse(
            vec![received(
                d,
                "x.zip",
                &zip_of(&[("a.ply", &[0u8; 4096])], stored),
            )],
            1000,
            "upload limit",
        );
        // A bomb: 200 MB of zeros deflate to a few hundred kilobytes.
        let mut w = zip::ZipWriter::new(std::io::Cursor::new(Vec::new()));
        let opts = zip::write::SimpleFileOptions::default()
            .compression_method(zip::CompressionMethod::Deflated)
            .large_file(true);
        w.start_file("a.ply", opts).expect("start");
        let zeros = vec![0u8; 1 << 20];
        for _ in 0..200 {
            w.write_all(&zeros).expect("write");
        }
        let bomb = w.finish().expect("finish").into_inner();
        assert!(bomb.len() < 1 << 20);
        refuse(
            vec![received(d, "x.zip", &bomb)],
            u64::MAX,
            "times its size",
        );
        refuse(
            vec![received(d, "x.zip", b"PK"), received(d, "a.ply", b"ply")],
            1 << 20,
            "on its own",
        );
        // Nothing is left behind by a refusal.
        let left: Vec<_> = std::fs::read_dir(d).expect("read_dir").flatten().collect();
        assert!(left.is_empty(), "{left:?}");
    }
}
