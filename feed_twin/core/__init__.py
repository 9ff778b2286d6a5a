"""The bottom layer that plant, control and the rest share: it imports nothing else of feed_twin.

signals (the controller/drive boundary's slots), trig (sincos for the Park angle), smooth (the
smooth sign of regularised discontinuities), fma (fused multiply-add in compiled code),
validate (the range checks of parameter dataclasses) and config (the typed YAML loader every
parameter dataclass loads through).
"""
