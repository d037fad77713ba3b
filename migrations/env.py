"""Alembic environment. The URL is ``config.attributes["url"]`` when called from
``app.service.db.session.upgrade``, else the settings' database URL (plain ``alembic upgrade head``)."""

from logging.config import fileConfig

from alembic import context
from sqlalchemy import pool
from sqlalchemy.engine import create_engine

from app.service.db.models import Base

config = context.config
url = config.attributes.get("url")
if url is None:
    from app.settings import Settings

    url = Settings().effective_database_url
    if config.config_file_name is not None:
        # Only on the command line: inside the service it would replace the app's logging setup.
        fileConfig(config.config_file_name)


def run_migrations_offline() -> None:
    context.configure(url=url, target_metadata=Base.metadata, literal_binds=True,
                      render_as_batch=url.startswith("sqlite"))
    with context.begin_transaction():
        context.run_migrations()


def run_migrations_online() -> None:
    engine = create_engine(url, poolclass=pool.NullPool)
    with engine.connect() as connection:
        context.configure(connection=connection, target_metadata=Base.metadata,
                          render_as_batch=connection.dialect.name == "sqlite")
        with context.begin_transaction():
            context.run_migrations()
    engine.dispose()


if context.is_offline_mode():
    run_migrations_offline()
else:
    run_migrations_online()
