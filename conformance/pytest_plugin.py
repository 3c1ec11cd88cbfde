"""pytest plugin of the conformance suite (work in progress: registers nothing yet)."""
