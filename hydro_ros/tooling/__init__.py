"""The repository's tools: bench/results' writer, the papers' claims against it and the generated docs (not installed)."""
