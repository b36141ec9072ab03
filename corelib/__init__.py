"""The common base every package builds on: file writes that are whole or absent, hashing,
strict config loading and output-folder locking. It imports nothing from `scenes`, `synth`,
`mcdp` or `study` (docs/DESIGN.md, "Layers")."""
