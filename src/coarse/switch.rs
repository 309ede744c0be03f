//! TEMPORARY (issue 11 ablation, helper "abl"): which parts of the coarse
//! search's change are on, read once from `DSMSTREAM_COARSE` (a comma list
//! of `clip`, `plane`, `keep`; `none` for none; unset: all three). To be
//! removed before merging, keeping only the parts that win.

use std::sync::OnceLock;

/// The parts of the change that are on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Switches {
    /// Rank the scan's minima and the refined candidates at one common clip.
    pub clip: bool,
    /// Fit a capped tilt plane to dh at every trial shift.
    pub plane: bool,
    /// Keep the georeferenced start unless beaten by `KEEP_SE` standard errors.
    pub keep: bool,
}

impl Switches {
    pub const ALL: Switches = Switches {
        clip: true,
        plane: true,
        keep: true,
    };

    pub fn parse(s: &str) -> Switches {
        let parts: Vec<&str> = s.split(',').map(str::trim).collect();
        for p in &parts {
            assert!(
                matches!(*p, "clip" | "plane" | "keep" | "none" | ""),
                "DSMSTREAM_COARSE: unknown part {p:?}"
            );
        }
        Switches {
            clip: parts.contains(&"clip"),
            plane: parts.contains(&"plane"),
            keep: parts.contains(&"keep"),
        }
    }
}

/// The switches of this process (`DSMSTREAM_COARSE`, read once).
pub fn get() -> Switches {
    static S: OnceLock<Switches> = OnceLock::new();
    *S.get_or_init(|| {
        let s = match std::env::var("DSMSTREAM_COARSE") {
            Ok(v) => Switches::parse(&v),
            Err(_) => Switches::ALL,
        };
        tracing::debug!(?s, "coarse search switches");
        s
    })
}
