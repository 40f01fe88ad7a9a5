"""The live monitor and operator console of a run: a local web page that follows the record as
steps are committed, and pauses, resumes or stops the run through its control socket
(docs/monitor.md)."""
