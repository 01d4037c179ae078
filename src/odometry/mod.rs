//! The geometry core of the paper, one stage per file (sections 2 to 3.2).
