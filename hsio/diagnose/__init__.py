"""Model-vs-data diagnostics of a servo-hydraulic actuator, of a specimen, and of a hybrid run.

Replay the emulator's actuator model against a measured command, show where the prediction
departs from the measurement, name the physical cause, extend the model with it and measure
the gain on data the fit did not see. See docs/diagnose.md.

Modules: :mod:`~hsio.diagnose.record` (the measured record), :mod:`~hsio.diagnose.readers`
(CSV, DAQ text export, hsio runs), :mod:`~hsio.diagnose.model` (the simulator),
:mod:`~hsio.diagnose.loop_rate` (the simulator at the controller's rate beside a slower record),
:mod:`~hsio.diagnose.effects` (the candidate causes), :mod:`~hsio.diagnose.fitting`,
:mod:`~hsio.diagnose.selection` (:func:`~hsio.diagnose.selection.diagnose`),
:mod:`~hsio.diagnose.modelfile` (the extended model as TOML, read by the emulator and
``hsio run``), :mod:`~hsio.diagnose.report` (plots and text), :mod:`~hsio.diagnose.synth`
(records from the emulator), :mod:`~hsio.diagnose.residual` (the sensor floor and what a
residual still holds), :mod:`~hsio.diagnose.specimen_record`, :mod:`~hsio.diagnose.specimen_fit`
and :mod:`~hsio.diagnose.specimen_report` (the specimen diagnosis, whose model is
hsio.specimens.diagnosed) and :mod:`~hsio.diagnose.budget` (the error budget of a hybrid run).
The package imports nothing heavy by itself.
"""
