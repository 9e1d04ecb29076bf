"""A second recording generator, written apart from gateway.core.simulator.

It shares nothing with the simulator, its sensor effects or its motion profiles (a test
checks the imports): the motion is a jerk-limited S-curve (motion.py), the ADXL202 is
its analogue chain on a fine time grid with its own discrete output filter and a
duty-cycle modulator read by the 8051's edge capture (board.py), the serial link adds
4 ms latency with 0.3 ms jitter, the other axis moves on its own, and each part has
its own offset, sensitivity (within 1 %) and filter capacitor (within 10 %).
Hidden effects are drawn in cases.py. Everything it knows comes from
/work/shared/spec (the data sheet and board facts), not from the simulator's code.
"""
