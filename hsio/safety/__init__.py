"""Safe lab sessions (docs/safety.md): the dry run before the hydraulics, the interlocks of the
control loop, confirmed holds, operator control (pause, resume, stop, signals) and exit statuses."""
