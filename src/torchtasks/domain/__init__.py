"""Domain randomization's core: the fields an env can vary per env (:mod:`torchtasks.domain.fields`)."""

from torchtasks.domain.fields import DomainEnv, DomainField, check_field_name, check_in_field

__all__ = ["DomainEnv", "DomainField", "check_field_name", "check_in_field"]
