"""The package's fixed outside face (docs/interface.md): topic names, fault and effect names,
sample and trajectory types, the typed machine config, and the one error family for bad input."""
