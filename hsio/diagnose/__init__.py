"""Model-vs-data diagnostics of a servo-hydraulic actuator.

Replay the emulator's actuator model against a measured command, show where the prediction
departs from the measurement, name the physical cause, extend the model with it and measure
the gain on data the fit did not see. See docs/diagnose.md.

Modules: :mod:`~hsio.diagnose.record` (the measured record), :mod:`~hsio.diagnose.readers`
(CSV, DAQ text export, hsio runs), :mod:`~hsio.diagnose.model` (the simulator),
:mod:`~hsio.diagnose.effects` (the candidate causes), :mod:`~hsio.diagnose.fitting`,
:mod:`~hsio.diagnose.selection` (:func:`~hsio.diagnose.selection.diagnose`),
:mod:`~hsio.diagnose.modelfile` (the extended model as TOML, read by the emulator and
``hsio run``), :mod:`~hsio.diagnose.report` (plots and text) and :mod:`~hsio.diagnose.synth`
(records from the emulator). The package imports nothing heavy by itself.
"""
