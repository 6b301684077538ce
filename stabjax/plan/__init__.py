"""The plan: a sweep spec (TOML) checked field by field and resolved into a frozen Plan; starts from a file; the identity that a resumed run must match."""
