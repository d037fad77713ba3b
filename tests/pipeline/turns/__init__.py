"""Finding the turns and planning the journey (``steps.turns``, ``steps.image_turns``,
``steps.plan``): RDP on the GPS track, the image look where it shows none, and the plan made from
them."""
