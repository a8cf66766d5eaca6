//! Filled by a later issue (see DESIGN.md, method map).
