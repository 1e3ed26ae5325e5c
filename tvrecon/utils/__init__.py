"""The bottom layer, importing nothing of tvrecon: atomic file writes, config coercion and checks, mesh and frame
geometry, checkpoint checks, command-line error handling, tensor shape checks."""
