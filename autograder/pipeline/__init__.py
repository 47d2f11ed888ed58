"""The grader's line, one module per stage (docs/architecture.md)."""
