"""ilcpmac: identify and compensate the torque ripple of PM AC motors.

Follows Grassens (2009), "Transfer function determination for a PM
synchronous AC motor" (the report), and goes beyond it with a joint
least-squares identification and iterative learning control.
"""

__version__ = "0.1.0"
