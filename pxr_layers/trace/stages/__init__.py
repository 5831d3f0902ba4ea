"""The integrator's stages, one module each, in schedule order (integrator.py):

camera → intersect → escaped → emission → surface → next_event → scatter → roulette, and
film, which sums what they contribute. Stages talk through the queues of queues.py; each
is a Python function that hands its queue to one compiled kernel (compiled.py).
"""
