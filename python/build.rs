// The commit the extension is built from, for the traceability block: the application's
// build script, whose crate sits at the same depth in the checkout.
include!("../host/build_commit.rs");
