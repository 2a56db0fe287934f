"""The `ports.HandInput`s: tracked sources (`tracked`), a recorded session (`recorded`) and
the built-in demo operator (`demo`)."""
