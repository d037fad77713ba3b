"""What the camera records of the street: ``lens`` (the wide-angle radial model and its inverse),
``scene`` (the world packed for ray casting), ``render`` (the exact ray-cast frames), ``effects``
(blur, exposure drift, sensor noise) and ``detect`` (the on-board detector's boxes)."""
