"""Routes by resource, one ``APIRouter`` each: ``journeys`` (/journeys: upload, status, signs,
delete), ``map`` (/signs: the fused map, one sign with its evidence, changes since) and ``tiles``
(/tiles/{z}/{x}/{y}.mvt)."""
