"""Real-time hybrid simulation (RTHS) on the virtual benchmark of Silva et al. (2020).

The benchmark is a 3-storey frame whose first storey is the physical (experimental) substructure,
driven by a servo-hydraulic actuator whose identified model is the "control plant" (Silva et al.
2020, Table 2, Fig. 11, eqs. 21-22). This package is self-contained in SI units (kg, N, m, s),
the units of the benchmark; nothing in it touches hsio's kN/mm core.

Modules, one job each:

- ``benchmark``: the benchmark's data (reference model, partitioning cases, ground motion);
- ``plant``: the control plant as an emulator model (nominal or perturbed), converters, noise;
- ``stage``: a tracking controller as a discrete stage of the loop;
- ``pi_lead``, ``ats``, ``amb``: the tracking controllers (``controllers`` lists them by name);
- ``loop``: the RTHS loop at the controller rate (numba when installed, pure Python otherwise,
  same numbers; ``jit`` chooses);
- ``criteria``: the evaluation criteria J1-J9;
- ``evaluate``: cases x controllers x plants, nominal and perturbed;
- ``realtime``: a periodic loop for the lab (sleep, then busy-wait) and its timing statistics.

The same plant as a stand-alone emulated device is ``hsio.emulators.vrths_plant``.
"""
