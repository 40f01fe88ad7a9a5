"""hsio: hybrid simulation of structures.

Units everywhere inside hsio: kN, mm, s; mass in kN s^2/mm (METHOD.md).
"""

__version__ = "0.1.0"
