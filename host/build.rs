// The commit the binary is built from, for the traceability block of its outputs
// (docs/formats.md, "Traceability"): `git describe --always --dirty`, or "unknown"
// outside a git checkout.
include!("build_commit.rs");
