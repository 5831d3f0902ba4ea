"""The integrator's stages, one module each, in schedule order (integrator.py):

camera → intersect → escaped → emission → surface → next_event → scatter → roulette.
Stages talk through the queues of queues.py; each is a Python function that hands its
queue to one compiled kernel (pxr_layers/compiled.py). What they contribute goes to the
batch's observers (observer.py), the film (film.py) first.
"""
