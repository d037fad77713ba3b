"""The map as vector tiles (base path /api/v1), admitted by a reader key (route ``dependencies``),
so the dashboard serves the same function behind its own sign-in."""

from __future__ import annotations

from fastapi import APIRouter, HTTPException, Request, Response, status

from app.service.api.routes.map import READER
from app.service.api.schemas import AUTH_ERRORS, ErrorOut
from app.service.db.map_read import heavy_read, read_connection
from app.service.db.map_tiles import MEDIA_TYPE, Tile, TileCache, encode, map_version, tile_features
from app.service.deps import SettingsDep

router = APIRouter(prefix="/api/v1")


TILE_DESCRIPTION = (
    "Web Mercator tiles numbered as OpenStreetMap's. One layer `signs` of points with `id`, "
    "`class`, `state` and `count` (1 for a sign); at low zoom, and in a tile with too many signs, "
    "a point stands for a cluster: `count` signs, `id` the smallest of theirs, `class`/`state` "
    "only when all members share one. Low-zoom tiles are cached until the map changes.")


@router.get("/tiles/{z}/{x}/{y}.mvt", response_class=Response, dependencies=READER,
            summary="The map's signs as a vector tile (Mapbox Vector Tile)",
            description=TILE_DESCRIPTION,
            responses={200: {"content": {MEDIA_TYPE: {}}, "description": "the tile"},
                       400: {"model": ErrorOut, "description": "z, x or y out of range"},
                       **AUTH_ERRORS})
async def get_tile(request: Request, settings: SettingsDep, z: int, x: int, y: int) -> Response:
    try:
        tile = Tile.checked(z, x, y, settings.tile_max_zoom)
    except ValueError as exc:
        raise HTTPException(status.HTTP_400_BAD_REQUEST, str(exc)) from exc

    cache = _tile_cache(request) if z <= settings.tile_cache_max_zoom else None

    def read() -> bytes:
        with read_connection(settings.effective_database_url) as conn:
            version = map_version(conn) if cache is not None else None
            data = cache.get((z, x, y), version) if cache is not None else None
            if data is None:
                data = encode(tile_features(
                    conn, tile, points_min_zoom=settings.tile_points_min_zoom,
                    max_points=settings.tile_max_points, grid=settings.tile_cluster_grid))
                if cache is not None:
                    cache.put((z, x, y), version, data)
        return data

    return Response(await heavy_read(request, read), media_type=MEDIA_TYPE)


def _tile_cache(request: Request) -> TileCache:
    cache = getattr(request.app.state, "tile_cache", None)
    if cache is None:
        settings = request.app.state.settings
        cache = request.app.state.tile_cache = TileCache(size=settings.tile_cache_size,
                                                         ttl_s=settings.tile_cache_ttl_s)
    return cache
