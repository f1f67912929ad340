# The ROS 2 Jazzy wheels on PyPI were built in a manylinux container. The
# Python-binding targets they export (e.g. std_msgs::std_msgs__rosidl_generator_py)
# name that container's Python and NumPy header directories
# (/opt/python/cp311-cp311/include/python3.11,
#  /opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include)
# in INTERFACE_INCLUDE_DIRECTORIES.
# It does not exist on the machine that builds this package, and CMake refuses
# to generate when an imported target lists a non-existent path.
#
# repair_imported_python_includes() walks every imported target of the current
# directory and, for each include directory that does not exist and looks like
# a Python or NumPy header directory, substitutes the headers of the
# interpreter this build uses (Python3_INCLUDE_DIRS, Python3_NumPy_INCLUDE_DIRS).
# Other non-existent paths are left alone so
# that a real packaging fault still fails loudly.
function(repair_imported_python_includes)
  if(NOT Python3_INCLUDE_DIRS OR NOT Python3_NumPy_INCLUDE_DIRS)
    message(FATAL_ERROR "find_package(Python3 ... Development.Module NumPy) must run before repair_imported_python_includes()")
  endif()
  get_property(targets DIRECTORY PROPERTY IMPORTED_TARGETS)
  foreach(target IN LISTS targets)
    get_target_property(dirs ${target} INTERFACE_INCLUDE_DIRECTORIES)
    if(NOT dirs)
      continue()
    endif()
    set(repaired "")
    set(changed FALSE)
    foreach(dir IN LISTS dirs)
      if(EXISTS "${dir}")
        list(APPEND repaired "${dir}")
      elseif(dir MATCHES "/numpy/(_core|core)/include$")
        list(APPEND repaired ${Python3_NumPy_INCLUDE_DIRS})
        set(changed TRUE)
      elseif(dir MATCHES "/include/python3\\.[0-9]+$")
        list(APPEND repaired ${Python3_INCLUDE_DIRS})
        set(changed TRUE)
      else()
        list(APPEND repaired "${dir}")
      endif()
    endforeach()
    if(changed)
      list(REMOVE_DUPLICATES repaired)
      set_target_properties(${target} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${repaired}")
      message(STATUS "Repaired Python include directory of imported target ${target}")
    endif()
  endforeach()
endfunction()
