"""rdnet: simulate, restore and deblur with real-world degraded events.

Reproduces "Restoring Real-World Degraded Events Improves Deblurring Quality"
(RDNet, ACM MM 2024).
"""
__version__ = "0.1.0"
