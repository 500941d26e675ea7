//! The output directory of one run: nothing in it is replaced without the user's say, and
//! a run that fails leaves no folder behind.
//!
//! [`OutDir::prepare`] is called before any work: an absent directory is created, an
//! empty one is used, and one with files in it is refused unless the user passed
//! `--force` ([`Replace::Force`]), or an earlier run of the same command made it
//! ([`Replace::OwnEarlierRun`], for the demo's scratch folder: a marker file, [`MARKER`],
//! names the command; its files are replaced, others left alone; a folder the command
//! was forced into while it held other files is not marked). When the value is dropped
//! without [`OutDir::keep`]
//! (the run failed), a directory this run created is removed again with what it wrote,
//! and so are the parent folders it made for it (when still empty); one that existed
//! before is left as it is.

use std::path::{Path, PathBuf};

/// The marker file naming the command that wrote a directory.
pub const MARKER: &str = ".stereotac-output";

/// When an existing directory with files in it may be written into.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Replace {
    /// Never: the command offers no `--force` (recordings never write over files).
    Never,
    /// Not now: `--force` was not given; refuse with that fix.
    NotForced,
    /// The user said so (`--force`).
    Force,
    /// When an earlier run of `command` made it (its marker is there), or `--force`
    /// (`force`).
    OwnEarlierRun {
        /// The command's name, as written in the marker.
        command: &'static str,
        /// `--force` given.
        force: bool,
    },
}

impl Replace {
    /// [`Replace::Force`] when `--force` was given, else [`Replace::NotForced`].
    pub fn force_if(force: bool) -> Self {
        if force { Self::Force } else { Self::NotForced }
    }
}

/// Why the directory cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum OutDirError {
    /// Files are in it and replacing them was not allowed.
    #[error(
        "{}: exists and holds {count} file(s) (e.g. {example}): {}",
        path.display(),
        if *forcible { "pass --force to write into it anyway, or choose another folder" } else { "choose another folder (nothing is ever written over files)" }
    )]
    NotEmpty {
        /// The directory.
        path: PathBuf,
        /// Entries found.
        count: usize,
        /// One of them.
        example: String,
        /// Whether `--force` would allow it.
        forcible: bool,
    },
    /// It, or a folder it would be made in, is a file.
    #[error(
        "{}: {} is a file, not a folder: give a folder for the outputs",
        path.display(),
        blocker.display()
    )]
    NotAFolder {
        /// The directory asked for.
        path: PathBuf,
        /// The file in its place, or in the place of one of its parents.
        blocker: PathBuf,
    },
    /// A symbolic link whose target is missing (an unmounted drive, a moved folder).
    #[error(
        "{}: a symbolic link to {}, which does not exist: give a folder for the outputs \
         (or make the one it points to)",
        path.display(),
        target.display()
    )]
    DanglingLink {
        /// The directory asked for.
        path: PathBuf,
        /// Where the link points.
        target: PathBuf,
    },
    /// A run allowed to write among its files would write through a link in it.
    #[error(
        "{}: holds a symbolic link, {} -> {}: a file written there would replace what \
         the link points to, outside this folder; remove the link or choose another folder",
        path.display(),
        link.display(),
        target.display()
    )]
    HoldsLink {
        /// The directory.
        path: PathBuf,
        /// The link.
        link: PathBuf,
        /// What it points to.
        target: PathBuf,
    },
    /// It could not be read or created.
    #[error("{}: {source}", path.display())]
    Io {
        /// The directory.
        path: PathBuf,
        /// Cause.
        source: std::io::Error,
    },
}

/// The file that stands where folder `path` or one of its parents should be (the
/// nearest of them that exists, when it is not a folder); `None` when the folder is
/// there or can be made.
pub fn file_in_the_way(path: &Path) -> Option<&Path> {
    path.ancestors()
        .filter(|p| !p.as_os_str().is_empty())
        .find(|p| p.exists())
        .filter(|p| !p.is_dir())
}

/// An output directory prepared for one run (see the module documentation).
#[derive(Debug)]
pub struct OutDir {
    path: PathBuf,
    created: bool,
    /// Parent folders this run made for the directory, nearest first.
    created_parents: Vec<PathBuf>,
    kept: bool,
}

impl OutDir {
    /// Checks and creates `path` before any work (see the module documentation).
    pub fn prepare(path: &Path, replace: Replace) -> Result<Self, OutDirError> {
        let io = |source| OutDirError::Io {
            path: path.to_path_buf(),
            source,
        };
        // `symlink_metadata`: a symlink whose target is missing is there (and is refused
        // below as unreadable), never made or removed.
        // A file where the folder (or one of its parents) should be: said as such, not
        // as "Not a directory (os error 20)".
        if let Some(blocker) = file_in_the_way(path) {
            return Err(OutDirError::NotAFolder {
                path: path.to_path_buf(),
                blocker: blocker.to_path_buf(),
            });
        }
        let mut dir = Self {
            path: path.to_path_buf(),
            created: false,
            created_parents: Vec::new(),
            kept: false,
        };
        if std::fs::symlink_metadata(path).is_err() {
            let mut made = make_dirs(path).map_err(io)?;
            dir.created = made.last().is_some_and(|d| d == path);
            if dir.created {
                made.pop();
            }
            made.reverse();
            // Dropped on a refusal below, `dir` removes what was made.
            dir.created_parents = made;
            if dir.created {
                dir.mark(replace)?;
                return Ok(dir);
            }
            // Not made by this run although it was not there as written (`new/../old`
            // reaches a folder that was, or one appeared meanwhile): checked as any
            // folder that was there.
        }
        if std::fs::symlink_metadata(path).is_ok_and(|m| m.file_type().is_symlink())
            && std::fs::metadata(path).is_err()
        {
            return Err(OutDirError::DanglingLink {
                path: path.to_path_buf(),
                target: std::fs::read_link(path).unwrap_or_default(),
            });
        }
        let entries: Vec<String> = std::fs::read_dir(path)
            .map_err(io)?
            .map(|e| e.map(|e| e.file_name().to_string_lossy().into_owned()))
            .collect::<Result<_, _>>()
            .map_err(io)?;
        // An empty folder needs no marker to be used: read only for one with files.
        let ours = match replace {
            Replace::OwnEarlierRun { command, .. } if !entries.is_empty() => {
                std::fs::read_to_string(path.join(MARKER)).is_ok_and(|m| m.trim() == command)
            }
            _ => false,
        };
        let allowed = entries.is_empty()
            || ours
            || matches!(
                replace,
                Replace::Force | Replace::OwnEarlierRun { force: true, .. }
            );
        if !allowed {
            let example = entries.iter().min().cloned().unwrap_or_default();
            return Err(OutDirError::NotEmpty {
                path: path.to_path_buf(),
                count: entries.len(),
                example,
                forcible: replace != Replace::Never,
            });
        }
        // Writing among files that are there: a file written through a link would
        // replace the link's target (an input image, a model), so a link is refused.
        if !entries.is_empty()
            && let Some(link) = link_inside(path)
        {
            let target = std::fs::read_link(&link).unwrap_or_default();
            return Err(OutDirError::HoldsLink {
                path: path.to_path_buf(),
                link,
                target,
            });
        }
        // Forced into a folder that held other files and was not this command's: it
        // stays the user's, unmarked, so a later run without `--force` is refused again
        // rather than taking it for its own.
        if entries.is_empty() || ours {
            dir.mark(replace)?;
        }
        Ok(dir)
    }

    /// Writes the marker for commands that replace their own earlier runs.
    fn mark(&self, replace: Replace) -> Result<(), OutDirError> {
        if let Replace::OwnEarlierRun { command, .. } = replace {
            let path = self.path.join(MARKER);
            std::fs::write(&path, format!("{command}\n"))
                .map_err(|source| OutDirError::Io { path, source })?;
        }
        Ok(())
    }

    /// The directory.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The run succeeded (or wrote what it reports): keep the directory.
    pub fn keep(mut self) -> PathBuf {
        self.kept = true;
        std::mem::take(&mut self.path)
    }
}

/// Folders below an output directory looked into for links (commands write into it and
/// into folders one level down).
const LINK_DEPTH: usize = 2;
/// Entries looked at for links at most: a folder given by mistake (a home folder) is
/// not walked whole.
const LINK_ENTRIES: usize = 10_000;

/// The first symbolic link in `dir` or in its folders down to [`LINK_DEPTH`] levels
/// (links to folders are not followed), looking at [`LINK_ENTRIES`] entries at most.
fn link_inside(dir: &Path) -> Option<PathBuf> {
    let mut folders = vec![(dir.to_path_buf(), 1)];
    let mut seen = 0;
    while let Some((folder, depth)) = folders.pop() {
        let Ok(read) = std::fs::read_dir(&folder) else {
            continue;
        };
        for entry in read.flatten() {
            seen += 1;
            if seen > LINK_ENTRIES {
                return None;
            }
            let Ok(kind) = entry.file_type() else {
                continue;
            };
            if kind.is_symlink() {
                return Some(entry.path());
            }
            if kind.is_dir() && depth < LINK_DEPTH {
                folders.push((entry.path(), depth + 1));
            }
        }
    }
    None
}

/// Makes `path` and the folders above it that are missing, one level at a time; returns
/// the folders this call made, outermost first (only those: a path through `..` or a
/// folder made meanwhile by someone else never counts another's folder as ours). On an
/// error the folders made are removed again.
fn make_dirs(path: &Path) -> std::io::Result<Vec<PathBuf>> {
    let mut made = Vec::new();
    let mut prefix = PathBuf::new();
    for component in path.components() {
        prefix.push(component);
        if std::fs::symlink_metadata(&prefix).is_ok() {
            continue;
        }
        match std::fs::create_dir(&prefix) {
            Ok(()) => made.push(prefix.clone()),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {}
            Err(e) => {
                for d in made.iter().rev() {
                    let _ = std::fs::remove_dir(d);
                }
                return Err(e);
            }
        }
    }
    Ok(made)
}

impl Drop for OutDir {
    fn drop(&mut self) {
        if self.kept {
            return;
        }
        if self.created {
            let _ = std::fs::remove_dir_all(&self.path);
        }
        // Only while empty: something else may have been put there meanwhile.
        for parent in &self.created_parents {
            if std::fs::remove_dir(parent).is_err() {
                break;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let d =
            std::env::temp_dir().join(format!("stereotac-outdir-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        d
    }

    #[test]
    fn a_failed_run_leaves_no_folder_and_a_kept_one_stays() {
        let d = scratch("fail");
        let dir = OutDir::prepare(&d.join("a/b"), Replace::Never).unwrap();
        std::fs::write(dir.path().join("partial.npy"), b"x").unwrap();
        drop(dir);
        // The parents it made for it go too (they were `reconstruct`'s empty leftovers).
        assert!(!d.join("a").exists() && !d.exists());
        // A parent something else wrote into meanwhile stays, with that file.
        let dir = OutDir::prepare(&d.join("a/b"), Replace::Never).unwrap();
        std::fs::write(d.join("a/other.txt"), b"x").unwrap();
        drop(dir);
        assert!(!d.join("a/b").exists() && d.join("a/other.txt").exists());
        // An empty parent that was there before stays; so does a user's folder reached
        // through `..` (it was there: not made by the run).
        std::fs::create_dir_all(d.join("empty")).unwrap();
        drop(OutDir::prepare(&d.join("empty/x/y"), Replace::Never).unwrap());
        assert!(d.join("empty").is_dir() && !d.join("empty/x").exists());
        std::fs::create_dir_all(d.join("users")).unwrap();
        drop(OutDir::prepare(&d.join("new/../users/run"), Replace::Never).unwrap());
        assert!(d.join("users").is_dir() && !d.join("users/run").exists());
        assert!(
            !d.join("new").exists(),
            "the folder made on the way goes too"
        );
        // Reached that way, a folder with files in it is refused as any other (the first
        // version wrote into it without --force), and the folder made on the way goes.
        std::fs::write(d.join("users/keep.txt"), b"x").unwrap();
        let e = OutDir::prepare(&d.join("new2/../users"), Replace::NotForced).unwrap_err();
        assert!(e.to_string().contains("--force"), "{e}");
        assert!(!d.join("new2").exists() && d.join("users/keep.txt").exists());
        // A symlink whose target is missing is refused, and left in place.
        #[cfg(unix)]
        {
            let link = d.join("dangling");
            std::os::unix::fs::symlink(d.join("unmounted/out"), &link).unwrap();
            let e = OutDir::prepare(&link, Replace::Never)
                .unwrap_err()
                .to_string();
            assert!(
                e.contains("a symbolic link to")
                    && e.contains("unmounted/out")
                    && e.contains("does not exist"),
                "{e}"
            );
            assert!(
                std::fs::symlink_metadata(&link).is_ok(),
                "the link was removed"
            );
            let inside = link.join("run");
            assert!(OutDir::prepare(&inside, Replace::Never).is_err());
            assert!(
                std::fs::symlink_metadata(&link).is_ok(),
                "the link was removed"
            );
        }
        let dir = OutDir::prepare(&d.join("c"), Replace::Never).unwrap();
        std::fs::write(dir.path().join("depth.npy"), b"x").unwrap();
        assert_eq!(dir.keep(), d.join("c"));
        assert!(d.join("c/depth.npy").exists());
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn files_already_there_are_refused_unless_forced_or_our_own() {
        let d = scratch("full");
        std::fs::create_dir_all(&d).unwrap();
        // An existing empty directory is used, and not removed on failure.
        drop(OutDir::prepare(&d, Replace::Never).unwrap());
        assert!(d.exists());
        std::fs::write(d.join("mine.txt"), b"user data").unwrap();
        let e = OutDir::prepare(&d, Replace::NotForced)
            .unwrap_err()
            .to_string();
        assert!(e.contains("mine.txt") && e.contains("--force"), "{e}");
        let e = OutDir::prepare(&d, Replace::Never).unwrap_err().to_string();
        assert!(e.contains("mine.txt") && !e.contains("--force"), "{e}");
        OutDir::prepare(&d, Replace::Force).unwrap().keep();
        let demo = Replace::OwnEarlierRun {
            command: "demo",
            force: false,
        };
        assert!(
            OutDir::prepare(&d, demo).is_err(),
            "not marked as the demo's"
        );
        // Forced into the user's folder, the demo does not mark it as its own: the
        // next run without --force is refused again.
        let forced = Replace::OwnEarlierRun {
            command: "demo",
            force: true,
        };
        OutDir::prepare(&d, forced).unwrap().keep();
        assert!(
            !d.join(MARKER).exists(),
            "the user's folder marked as the demo's"
        );
        let e = OutDir::prepare(&d, demo).unwrap_err().to_string();
        assert!(e.contains("mine.txt") && e.contains("--force"), "{e}");
        let e2 = scratch("own");
        OutDir::prepare(&e2, demo).unwrap().keep();
        std::fs::write(e2.join("depth.npy"), b"x").unwrap();
        OutDir::prepare(&e2, demo).unwrap().keep();
        let other = Replace::OwnEarlierRun {
            command: "stereo",
            force: false,
        };
        assert!(
            OutDir::prepare(&e2, other).is_err(),
            "another command's folder"
        );
        let _ = std::fs::remove_dir_all(&d);
        let _ = std::fs::remove_dir_all(&e2);
    }

    /// A folder a run may write among the files of (forced, or its own) is refused when
    /// it holds a link, here or one folder down: `--force` writing `depth16.png` through
    /// a link replaced the input image it pointed to.
    #[cfg(unix)]
    #[test]
    fn a_link_in_a_folder_written_among_its_files_is_refused() {
        let d = scratch("links");
        let out = d.join("out");
        std::fs::create_dir_all(out.join("sub")).unwrap();
        std::fs::write(d.join("input.png"), b"the user's image").unwrap();
        std::fs::write(out.join("old.txt"), b"x").unwrap();
        OutDir::prepare(&out, Replace::Force).unwrap().keep();
        for link in [out.join("sub/depth16.png"), out.join("depth16.png")] {
            std::os::unix::fs::symlink(d.join("input.png"), &link).unwrap();
            let e = OutDir::prepare(&out, Replace::Force)
                .unwrap_err()
                .to_string();
            assert!(
                e.contains("depth16.png")
                    && e.contains("input.png")
                    && e.contains("remove the link"),
                "{e}"
            );
            std::fs::remove_file(&link).unwrap();
        }
        assert_eq!(
            std::fs::read(d.join("input.png")).unwrap(),
            b"the user's image"
        );
        let _ = std::fs::remove_dir_all(&d);
    }
}
