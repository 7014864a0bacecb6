"""The application layer: configuration and its schema, preflight checks, workflows, the command
line, outputs and figures, the paper's experiment."""
