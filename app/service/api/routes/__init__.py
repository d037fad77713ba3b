"""Routes by resource: ``journeys`` (/journeys...), ``map`` (/signs...), ``tiles`` (/tiles...)."""
